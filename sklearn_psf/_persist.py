"""How an estimator writes and reads its own fitted state (the persistence protocol).

Each class that a model file stores knows its own fitted attributes, as PIFF's classes
write and read themselves; the model file (:mod:`sklearn_psf.model._file`) is only a
container that writes each part's parameters and state and asks the part's class to restore
it.

- ``_get_state(self) -> dict``: the fitted state, keyed by attribute name (the estimator's
  own namespace; a container nests each part's state under the part's name). Values are
  JSON-able scalars (``int``, ``float``, ``bool``, ``str``, ``None``), lists of them, and
  numpy arrays.
- ``_set_state(self, state) -> self``: called on ``cls(**params)`` built with the saved
  parameters (``get_params(deep=False)``), it restores the estimator as fitted: no fit, no
  optimisation, no likelihood.

:class:`StateMixin` implements both from the class attribute ``_state_attributes`` (the
names of the fitted attributes to store); a class adds to it what its parent lists, and
overrides ``_set_state`` for what cannot be set as it is (``_n_features_out`` of a
transformer, a structure rebuilt from arrays).

Interpolators are the exception that the container knows: their prediction is a solve on
the stars they were fitted on (Kriging's system, a polynomial's least squares), and those
stars are the model's (the ``STARS`` table). Their state is what their fit *chose* from the
data (Kriging's hyperparameters and drift, a polynomial's degree); ``_set_state`` holds it
so that their next ``fit`` only solves with it, and the container fits them on the stored
stars. An estimator without ``_get_state`` (scikit-learn's, or a scheme that chooses
nothing: Shepard, Delaunay, RBF, the position scalers) is fitted on the stored data, which
is deterministic.
"""

from __future__ import annotations

import numpy as np

__all__ = ["StateMixin"]


class StateMixin:
    """``_get_state`` / ``_set_state`` of the fitted attributes named in
    ``_state_attributes`` (see the module's description)."""

    #: names of the fitted attributes that make the estimator's state; an attribute absent
    #: from a fitted estimator (an optional one) is left out of its state
    _state_attributes: tuple = ()

    def _get_state(self) -> dict:
        return {name: _plain(getattr(self, name)) for name in self._state_attributes
                if hasattr(self, name)}

    def _set_state(self, state: dict):
        for name, value in state.items():
            if name not in self._state_attributes:
                raise ValueError(f"{type(self).__name__} has no fitted attribute {name!r} to "
                                 "restore: the model file comes from another version.")
            setattr(self, name, value)
        return self


def _plain(value):
    """numpy scalars as Python's (JSON-able); arrays as they are."""
    if isinstance(value, np.generic):
        return value.item()
    return value
