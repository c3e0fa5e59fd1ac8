"""
========================================
Tune the Kriging range with GridSearchCV
========================================

On real data there are no galaxy-PSFs with a known PSF: the only way to choose the
hyperparameters of an interpolation scheme is to hold out some stars. Because
:class:`~sklearn_psf.model.PSFModel` is a scikit-learn estimator, :class:`~sklearn.model_selection.GridSearchCV`
does it with a K-fold split of the stars and the residual ellipticity correlation (rho1) of
the held-out stars as the score. The paper tuned the Kriging range by hand; here it is a
grid search over the range and the nugget of the variogram.
"""

# %%
# Stars of one simulated field
# ----------------------------
import os

import matplotlib.pyplot as plt
import numpy as np
from sklearn.model_selection import GridSearchCV, KFold
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import MinMaxScaler

from sklearn_psf import KrigingRegressor, PSFModel, make_psf_field
from sklearn_psf.metrics import make_rho1_scorer

SIZE = os.environ.get("SKLEARN_PSF_EXAMPLE_SIZE", "full")
if SIZE == "small":
    image_shape, n_stars = (1500, 2000), 300
else:
    image_shape, n_stars = (7769, 10032), 1000

field = make_psf_field(n_stars=n_stars, n_galaxies=0, image_shape=image_shape, random_state=2)
stamps, flags = field.star_stamps()
X = np.column_stack([field.stars["x"], field.stars["y"]]).astype(float)[flags == 0]
y = stamps[flags == 0]

# %%
# The model and its nested parameters
# -----------------------------------
# The interpolator's parameters are reached as ``interpolator__<step>__<parameter>``
# (``PSFModel()`` accepts them too: ``set_params`` builds its default pipeline first; passing
# the pipeline explicitly also lists them in ``get_params``): here ``interpolator__krigingregressor__range`` (in
# units of the scaled positions, the image being mapped to the unit square) and
# ``interpolator__krigingregressor__nugget`` (fraction of the variogram's sill).
model = PSFModel(interpolator=make_pipeline(MinMaxScaler(), KrigingRegressor()))
print(sorted(k for k in model.get_params() if k.startswith("interpolator__kriging")))

# %%
# Grid search with K-fold on the stars
# ------------------------------------
# The score is minus the mean :math:`|\rho_1|` of the held-out stars (their measured, noisy stamps
# against the model's prediction) between 1/20 and 3/4 of the image width.
width = image_shape[1]
param_grid = {
    "interpolator__krigingregressor__range": [0.05, 0.1, 0.25, 0.5, 1.0, 2.0],
    "interpolator__krigingregressor__nugget": [0.0, 0.05],
}
search = GridSearchCV(
    model,
    param_grid,
    scoring=make_rho1_scorer(width / 20, 0.75 * width, nbins=6),
    cv=KFold(5, shuffle=True, random_state=0),
)
search.fit(X, y)
print("best parameters:", search.best_params_)
print(f"best score (minus mean |rho1|): {search.best_score_:.3e}")

# %%
# Score against the range
# -----------------------
# One curve per nugget, with the spread over the five folds. A small range makes Kriging
# fall back to the mean of the stars away from them; a large one makes it smoother.
results = search.cv_results_
ranges = np.asarray(param_grid["interpolator__krigingregressor__range"])
fig, ax = plt.subplots(figsize=(6, 4), layout="constrained")
for nugget, marker in zip(param_grid["interpolator__krigingregressor__nugget"], "os"):
    sel = np.asarray(results["param_interpolator__krigingregressor__nugget"]) == nugget
    order = np.argsort(np.asarray(results["param_interpolator__krigingregressor__range"])[sel])
    mean = -results["mean_test_score"][sel][order]
    std = results["std_test_score"][sel][order]
    ax.errorbar(ranges, mean, yerr=std, marker=marker, capsize=3, label=f"nugget = {nugget}")
ax.set_xscale("log")
ax.set_xlabel("Kriging range (unit-square units)")
ax.set_ylabel("mean |rho1| of held-out stars")
ax.legend()
plt.show()
