"""The fine grid of :class:`~sklearn_psf.preprocessing.SuperResolvedPCA`: its geometry and
Fourier operators (drawing fine images at a star's pixels for its sub-pixel offset, by two
1-D periodic sinc matrices, and the adjoint), the joint least-squares fits through all stars
of the fine images (conjugate gradients on normal equations computed once per solve as a
convolution in frequency) and of the refinement's polynomial, and the band limit of the
images (the disc of frequencies they hold, and its ``"auto"`` choice with the mean's
support: the disc and the radius whose mean, fitted on half of the stars, best predicts
the other half). They live on :class:`_FineGrid`, a mixin that ``SuperResolvedPCA``
inherits: the star fits, the components and the estimator API stay in ``_superres``."""

from __future__ import annotations

import numpy as np
from scipy import fft as sfft
from scipy.fft import next_fast_len

_CHUNK = 64  # stars at once (the arrays of a chunk stay in the caches)
_CG_ITER = 100
_CG_TOL = 1e-7  # relative residual of the conjugate gradients (a Gauss-Newton step: _GN_TOL)
_BAND_STEP = 0.1  # cycles per pixel: the step of the radii band_limit="auto" tries
_SUPPORTS = (3.0, 4.0, 5.0, 6.0, 8.0, 10.0, np.inf)  # pixels: support_radius="auto"'s
_FIT_RADIUS = 12.0  # pixels: fit_size="auto" models at least this far from the star (at
# 10, Euclid-like stars lost accuracy: e rms at the truth 0.00271 -> 0.00278)
_FIT_FWHMS = 5.0  # and this many FWHMs
_BAND_STARS = 2.5  # band_limit="auto": usable stars per half and per fine sample of a pixel,
# at least (10 per half at oversampling 2: with fewer the halves' fits stop short of the
# band that all the stars resolve, e.g. 0.57-0.67 cycle per pixel for 2-12 Euclid-like stars)


class _FineGrid:
    """The fine grid's geometry, draws, joint fit and band limit (a mixin of
    :class:`~sklearn_psf.preprocessing.SuperResolvedPCA`, which sets ``fit_size_`` (the
    side of the square of pixels the grid models), ``oversampling_`` and ``band_limit_``
    before using them)."""

    # -- geometry -----------------------------------------------------------------------------
    def _grid(self, s):
        f = self.oversampling_
        size = f * s if (f * s) % 2 else f * s + 1
        return f, size, (size - 1) // 2 - f * ((s - 1) // 2)  # factor, side, first sample

    def _fit_side(self, s):
        """Side of the square about each star that the fine images model (``fit_size``):
        "auto", ``2 * max(_FIT_RADIUS, _FIT_FWHMS * fwhm_) + 1`` pixels, within the stamp
        of side ``s``."""
        t = self.fit_size
        if t == "auto":
            radius = max(_FIT_RADIUS, _FIT_FWHMS * self.fwhm_) if np.isfinite(self.fwhm_) \
                else np.inf
            t = 2 * int(np.ceil(radius)) + 1 if np.isfinite(radius) else s
        return s if t is None else min(int(t), s)

    @staticmethod
    def _crop(x, s, side):
        """Stamps (n, s*s) cut to their central ``side`` x ``side`` pixels (both odd)."""
        lo = (s - side) // 2
        return np.ascontiguousarray(
            x.reshape(-1, s, s)[:, lo:lo + side, lo:lo + side]).reshape(len(x), -1)

    @staticmethod
    def _embed(x, side, s):
        """Stamps (n, side*side) placed at the centre of stamps (n, s*s), 0 around them."""
        if side == s:
            return x
        out = np.zeros((len(x), s, s))
        lo = (s - side) // 2
        out[:, lo:lo + side, lo:lo + side] = x.reshape(-1, side, side)
        return out.reshape(len(x), -1)

    def _interp(self, shifts, derivative=False):
        """1-D matrices (b, s, S) drawing a fine image's rows (or columns) at the pixels of
        stars shifted by ``shifts`` (b,) pixels, so that a star's pixels are
        ``f**2 * Ly @ X @ Lx.T``: the fine grid's periodic sinc (Fourier) interpolation at
        the samples ``o + f r - f t`` (the Dirichlet kernel of the odd side S), what a
        Fourier shift of the fine grid followed by keeping every f-th sample gives, at
        O(s S) per row instead of an FFT of the grid per star and image. With
        ``derivative``, their derivatives along the shifts."""
        s = self.fit_size_
        f, size, o = self._grid(s)
        # sample - fine index: o + f r - c for row r, fine sample c, from first to last
        first, last = o - (size - 1), o + f * (s - 1)
        # the kernel at every lag (c - f t, c integer), then each row's lags taken from it:
        # row r is the window of the reversed lags starting at last - (o + f r)
        tau = np.pi / size * (np.arange(first, last + 1)[None, :]
                              - f * np.asarray(shifts, dtype=np.float64)[:, None])
        num, den = np.sin(size * tau), np.sin(tau)
        flat = np.abs(den) < 1e-12  # tau a multiple of pi: the kernel's peak, S / S = 1
        den = np.where(flat, 1.0, den)
        starts = last - o - f * np.arange(s)

        def rows(values):
            windows = np.lib.stride_tricks.sliding_window_view(values[:, ::-1], size, axis=1)
            return windows[:, starts]

        kernel = rows(np.where(flat, 1.0, num / (size * den)))
        if not derivative:
            return kernel
        # d/dt = -f pi / S d/dtau of sin(S tau) / (S sin tau); 0 at the peaks
        slope = (size * np.cos(size * tau) * den - num * np.cos(tau)) / (size * den**2)
        return kernel, rows(np.where(flat, 0.0, -f * np.pi / size * slope))

    def _draw(self, fine, offsets, a=None, gradient=False):
        """Stars' pixels (b, m, p) of the m fine images ``fine`` (m, S*S) at the b stars'
        ``offsets``; with ``a`` (b, m), of each star's combination ``a_b @ fine`` (b, p).
        With ``gradient``, also a function of ``amp`` (b, m), or (b, 1) with ``a``, giving
        the derivatives (b, 2, p) along the offsets (x, y) of the stars' images
        ``amp_b @ fine`` (``amp_b * a_b @ fine`` with ``a``)."""
        s = self.fit_size_
        f, size, _ = self._grid(s)
        b = len(offsets)
        if gradient:
            (ly, dly), (lx, dlx) = (self._interp(offsets[:, i], derivative=True) for i in (1, 0))
        else:
            ly, lx = self._interp(offsets[:, 1]), self._interp(offsets[:, 0])
        if a is None:  # each image's rows at the stars' phases, then their columns
            m = len(fine)
            images = fine.reshape(m, size, size)
            rows = ly @ images.transpose(1, 0, 2).reshape(size, m * size)
            rows = np.ascontiguousarray(rows.reshape(b, s, m, size).transpose(0, 2, 1, 3))
        else:
            images = (a @ fine).reshape(b, 1, size, size)
            rows = ly[:, None] @ images
        pix = (f * f) * (rows.reshape(b, -1, size) @ lx.transpose(0, 2, 1)).reshape(b, -1, s * s)
        if a is not None:
            pix = pix[:, 0]
        if not gradient:
            return pix

        def slope(amp):
            """d/d(offset x, y) of the stars' images weighted by ``amp``."""
            dx = np.einsum("bi,bisw->bsw", amp, rows) @ dlx.transpose(0, 2, 1)
            if a is None and len(fine) == 1:  # one image for all: its rows in one product
                dy = amp[:, :, None] * (dly.reshape(-1, size) @ images[0]).reshape(b, s, size)
            else:
                combined = (amp @ fine if a is None else amp * (a @ fine))
                dy = dly @ combined.reshape(b, size, size)
            dy = dy @ lx.transpose(0, 2, 1)
            return (f * f) * np.stack([dx, dy], axis=1).reshape(b, 2, s * s)

        return pix, slope

    def _draw_adjoint(self, pixels, offsets):
        """Adjoint of the draw for each star: pixels (b, q, p) -> fine images (b, q, S*S)."""
        s = self.fit_size_
        f, size, _ = self._grid(s)
        ly, lx = self._interp(offsets[:, 1]), self._interp(offsets[:, 0])
        out = ly.transpose(0, 2, 1)[:, None] @ pixels.reshape(len(pixels), -1, s, s) @ lx[:, None]
        return (f * f) * out.reshape(len(pixels), -1, size * size)

    def _support(self, fine):
        """0/1 per fine sample: where the mean exceeds 1e-2 of its peak, grown by one pixel
        (the components' support: beyond it they would fit noise)."""
        from scipy.ndimage import binary_dilation

        size = self._grid(self.fit_size_)[1]
        mean = fine[0].reshape(size, size)
        core = mean > 1e-2 * mean.max()
        return binary_dilation(core, iterations=self.oversampling_).ravel().astype(float)

    def _frame(self, fine):
        """Orthonormal rows spanning the fine mean and its x and y derivatives (the
        directions the stars' fluxes and offsets already take)."""
        size = self._grid(self.fit_size_)[1]
        fx = np.fft.rfft2(fine[0].reshape(size, size))
        ky = np.fft.fftfreq(size)[:, None]
        kx = np.fft.rfftfreq(size)[None, :]
        grads = np.fft.irfft2(np.stack([fx * 2j * np.pi * kx, fx * 2j * np.pi * ky]),
                              s=(size, size)).reshape(2, -1)
        rows = np.vstack([fine[:1], grads])
        if not np.abs(rows).sum():
            return np.zeros((0, size * size))
        q, _ = np.linalg.qr(rows.T)
        return q.T

    # -- the fine images' joint fit -----------------------------------------------------------
    def _fit_fine(self, target, u, a, offsets, fine0, J=None, tol=_CG_TOL, frame=None,
                  band=None):
        """Fine images x (m, S*S) minimising ``sum_n ||target_n - draw_n(a_n @ x)||^2`` in
        the pixel weights ``u`` (n, p), conjugate gradients from ``fine0``. With ``J`` (n, q, p),
        each star's residual is taken orthogonally (in ``u``) to the span of its rows: the
        star's own parameters (flux, coefficients, offset, background) are profiled out, so
        that ``target`` = the stars' residuals gives the Gauss-Newton step of all parameters
        together (variable projection). Rows of ``frame`` are kept out of the components'
        updates. Only the images' frequencies in ``band`` (default :meth:`_band`) are fitted."""
        n, m = a.shape
        size = self._grid(self.fit_size_)[1]
        # (``fine0`` comes band-limited, from :meth:`_settle`)
        band = self._band() if band is None else band

        def keep(x):  # components stay on the PSF's support (``frame``: 0/1 per sample)
            if frame is not None and m > 1:
                x = x.copy()
                x[1:] *= frame
            return x

        if J is not None:
            Ju = J * u[:, None, :]
            JuJ = np.linalg.pinv(Ju @ J.transpose(0, 2, 1), hermitian=True)

        def weigh(y, sl):
            out = u[sl] * y
            if J is not None:
                coef = (JuJ[sl] @ (Ju[sl] @ y[:, :, None]))[:, :, 0]
                out -= (coef[:, None, :] @ Ju[sl])[:, 0]
            return out

        normal = self._normal(u, a, offsets, band, keep, None if J is None else (Ju, JuJ))
        rhs = 0.0
        for lo in range(0, n, _CHUNK):
            sl = slice(lo, min(lo + _CHUNK, n))
            back = self._draw_adjoint(weigh(target[sl], sl)[:, None], offsets[sl])[:, 0]
            rhs = rhs + a[sl].T @ back
        rhs = keep(self._band_limited(rhs, band))
        # preconditioned by the images' typical coupling (sum_n a_n a_n^T times the star's
        # mean pixel weight); a small ridge keeps samples no star constrains at 0
        scale = (a * u.sum(axis=1)[:, None]).T @ a / size**2  # (m, m): the images' coupling
        diag = np.diag(scale).copy()
        scale[np.diag_indices(m)] = np.where(diag > 0, diag, 1.0)
        precond = np.linalg.pinv(scale, hermitian=True)
        ridge = 1e-8 * np.diag(scale)[:, None]
        x = fine0.copy()
        r = rhs - normal(x) - ridge * x
        z = precond @ r
        rz = float((r * z).sum())
        stop = tol**2 * float((rhs * (precond @ rhs)).sum())
        direction = z.copy()
        for _ in range(_CG_ITER):
            if rz <= stop:
                break
            q = normal(direction) + ridge * direction
            alpha = rz / float((direction * q).sum())
            x += alpha * direction
            r -= alpha * q
            z = precond @ r
            rz_new = float((r * z).sum())
            direction = z + (rz_new / rz) * direction
            rz = rz_new
        return x

    def _spatial_fit(self, r, u, flux, offsets, fine, terms):
        """Polynomial coefficients C (terms, components) minimising, in the pixel weights
        ``u``, ``sum_n ||r_n - flux_n draw_n((terms_n @ C) @ components)||^2``."""
        n, t = terms.shape
        k = fine.shape[0] - 1
        normal = np.zeros((t, k, t, k))
        rhs = np.zeros((t, k))
        for lo in range(0, n, _CHUNK):
            sl = slice(lo, min(lo + _CHUNK, n))
            drawn = self._draw(fine[1:], offsets[sl]) * flux[sl, None, None]
            du = drawn * u[sl, None]
            gram = du @ drawn.transpose(0, 2, 1)  # (b, k, k)
            normal += np.einsum("bp,bq,bjl->pjql", terms[sl], terms[sl], gram)
            rhs += np.einsum("bp,bj->pj", terms[sl], (du @ r[sl, :, None])[:, :, 0])
        normal = normal.reshape(t * k, t * k)
        sol = np.linalg.lstsq(normal, rhs.ravel(), rcond=1e-12)[0]
        return sol.reshape(t, k)

    def _normal(self, u, a, offsets, band, keep, projected=None):
        """The normal operator x -> sum_n a_n a_n^T (x) D_n^T W_n D_n x of the fine images'
        least squares (D_n: star n's draw, held to ``band``; W_n: its pixel weights ``u``,
        less the projection ``projected`` = (Ju, pinv(Ju J^T)) of its own parameters), with
        ``keep`` on both sides.

        Drawing a band-limited image at the pixels of a star at offset t samples its Fourier
        series at the points z = o + f r - f t, so in frequency the weighted sum over the
        stars is a convolution: (D^T W D x)^(k) = f^4 / S^2 B(k) sum_k' G(k - k') B(k')
        x^(k'), with G(q) = sum_(n, r) a_n a_n^T u_n(r) exp(-2 pi i q.z_nr / S) (a
        non-uniform Fourier sum of the weights, separable for each star's square of pixels)
        for the |q| <= 2K that the band's frequencies |k| <= K reach. It is computed once
        here and applied by FFTs of side L >= 4K + 1 (the convolution without
        wrap-around): a cost per iteration independent of the number of stars, instead of
        two FFTs of the fine grid per star and image (the Toeplitz form of non-uniform FFT
        least squares). The projection is rank q per star: the spectra of its images
        D_n^T Ju_n^T are kept, on the band."""
        n, m = a.shape
        s = self.fit_size_
        f, size, o = self._grid(s)
        half = (size + 1) // 2
        ky = np.round(np.fft.fftfreq(size) * size).astype(int)  # rfft2's rows' frequencies
        used = band > 0
        reach = max(int(np.abs(ky[used.any(axis=1)]).max(initial=0)),
                    int(np.flatnonzero(used.any(axis=0)).max(initial=0)))
        top = min(2 * reach, size - 1)
        big = next_fast_len(max(2 * top + 1, size), real=True)
        q = np.arange(-top, top + 1)
        base_y = np.exp(-2j * np.pi / size * np.outer(q, o + f * np.arange(s)))  # (2Q + 1, s)
        base_x = base_y[top:]  # q >= 0: the half plane (Q + 1, s)
        i, j = np.triu_indices(m)
        # (real and imaginary parts side by side: the sum over the stars as a real product)
        kernel = np.zeros((len(i), 2 * len(q) * (top + 1)))
        for lo in range(0, n, _CHUNK):
            sl = slice(lo, min(lo + _CHUNK, n))
            weights = u[sl].reshape(-1, s, s)
            left = np.empty((len(weights), len(q), s), dtype=complex)
            left.real, left.imag = base_y.real @ weights, base_y.imag @ weights
            left *= np.exp(2j * np.pi * f / size * q[None, :, None] * offsets[sl, 1, None, None])
            right = base_x.T * np.exp(2j * np.pi * f / size * q[None, None, top:]
                                      * offsets[sl, 0, None, None])
            h = left @ right  # (b, 2Q + 1, Q + 1)
            kernel += (a[sl, i] * a[sl, j]).T @ h.reshape(len(h), -1).view(np.float64)
        padded = np.zeros((len(i), big, big // 2 + 1), dtype=complex)
        padded[:, q % big, :top + 1] = kernel.view(complex).reshape(len(i), len(q), top + 1)
        # (in double precision: the ridge below is 1e-8 of the diagonal, and in single
        # precision, ~3e-7 of the output, the least constrained directions' curvature is
        # rounding, which made the conjugate gradients diverge on one fold of the SDSS frame)
        g = np.empty((m, m, big, big))
        g[i, j] = g[j, i] = sfft.irfft2(padded, s=(big, big)) * (big**2 * f**4 / size**2)
        rows = ky % big
        on = np.flatnonzero(used)  # the band's frequencies, and their weight in a real sum
        parseval = np.where(np.arange(half) == 0, 1.0, 2.0)[None, :].repeat(size, 0).ravel()[on]
        if projected is not None:  # the spectra on the band, real and imaginary parts
            Ju, JuJ = projected
            near = slice(top - reach, top + reach + 1)  # |k| <= K
            at = ((ky[:, None] + reach) * (reach + 1) + np.arange(half)[None, :]).ravel()[on]
            spectra = np.empty((n, Ju.shape[1], 2 * len(on)))
            for lo in range(0, n, _CHUNK):
                sl = slice(lo, min(lo + _CHUNK, n))
                h = base_y[None, near] * np.exp(2j * np.pi * f / size * q[None, near, None]
                                                * offsets[sl, 1, None, None])
                w = base_x[None, :reach + 1] * np.exp(2j * np.pi * f / size
                                                      * q[None, top:top + reach + 1, None]
                                                      * offsets[sl, 0, None, None])
                rows_j = Ju[sl].reshape(len(h), -1, s, s)
                left = np.empty(rows_j.shape[:2] + h.shape[1:], dtype=complex)
                left.real, left.imag = h.real[:, None] @ rows_j, h.imag[:, None] @ rows_j
                spec = (f * f) * (left @ w.transpose(0, 2, 1)[:, None])
                spec = spec.reshape(len(h), Ju.shape[1], -1)[:, :, at]
                spectra[sl, :, :len(on)], spectra[sl, :, len(on):] = spec.real, spec.imag
            spectra = spectra.reshape(-1, 2 * len(on))  # (n q, 2 band)

        def normal(x):
            spec = sfft.rfft2(keep(x).reshape(m, size, size)) * band
            padded = np.zeros((m, big, big // 2 + 1), dtype=complex)
            padded[:, rows, :half] = spec
            y = sfft.irfft2(padded, s=(big, big))
            conv = sfft.rfft2(np.einsum("ijyx,jyx->iyx", g, y))[:, rows, :half] * band
            if projected is not None:  # sum_z V x = sum_k Re(conj(V^) x^) / S^2, on the band
                flat = spec.reshape(m, -1)[:, on] * (parseval / size**2)
                flat = np.concatenate([flat.real, flat.imag], axis=1)
                z = np.einsum("nqm,nm->nq", (spectra @ flat.T).reshape(n, -1, m), a)
                c = (JuJ @ z[:, :, None])[:, :, 0]
                back = (c[:, :, None] * a[:, None, :]).reshape(-1, m).T @ spectra
                conv = conv.reshape(m, -1)
                conv[:, on] -= back[:, :len(on)] + 1j * back[:, len(on):]
            return keep(sfft.irfft2(conv.reshape(m, size, half), s=(size, size)).reshape(m, -1))

        return normal

    def _radius(self):
        """Radius (cycles per pixel) of each frequency of the fine grid's ``rfft2``."""
        size = self._grid(self.fit_size_)[1]
        k = np.hypot(np.fft.fftfreq(size)[:, None], np.fft.rfftfreq(size)[None, :])
        return k * self.oversampling_

    def _band(self):
        """0/1 per frequency of the fine grid's ``rfft2``: 1 within ``band_limit_`` cycles per
        pixel (a disc, clipped by the square grid's own Nyquist frequencies)."""
        return (self._radius() <= self.band_limit_).astype(float)

    def _choose_band_and_support(self, d, u, a, offsets, usable):
        """``band_limit_`` and ``support_radius_`` of the "auto" parameters, by the stars
        left out of half fits (:meth:`_held_out_choice`); with too few stars, the grid's
        Nyquist disc and the whole stamp."""
        nyquist = self.oversampling_ / 2.0
        bands = (np.arange(0.3, np.sqrt(2.0) * nyquist + 0.05, _BAND_STEP)
                 if self.band_limit == "auto" else [self.band_limit_])
        supports = _SUPPORTS if self.support_radius == "auto" else [self.support_radius_]
        chosen = self._held_out_choice(d, u, a, offsets, usable, bands, supports)
        if chosen is None:
            chosen = (nyquist if self.band_limit == "auto" else self.band_limit_,
                      np.inf if self.support_radius == "auto" else self.support_radius_)
        self.band_limit_, self.support_radius_ = chosen

    def _held_out_choice(self, d, u, a, offsets, usable, bands, supports):
        """``band_limit="auto"`` and ``support_radius="auto"``: the band (cycles per pixel)
        and the mean's support radius (pixels) among ``bands`` and ``supports`` that best
        predict stars a fit did not see. Two means are fitted, each on half of the usable
        stars over the whole square grid; each is held to every disc of frequencies and set
        to 0 beyond every radius, and drawn at the other half's stars (their offsets held,
        their flux and a constant background fitted); the pair of the least misfit summed
        over both halves, in the weights ``u``, is kept. None with fewer than
        ``2 * _BAND_STARS * oversampling**2`` usable stars (20 at oversampling 2)."""
        f, size, _ = self._grid(self.fit_size_)
        if usable.sum() < 2 * _BAND_STARS * f * f:  # too few stars to split
            return None
        k = self._radius()
        rows = np.flatnonzero(usable)
        halves = (rows[0::2], rows[1::2])
        masks = [self._disc(r) for r in supports]
        misfit = np.zeros((len(bands), len(supports)))
        for fitted, other in (halves, halves[::-1]):
            mean = self._fit_fine(d[fitted], u[fitted], a[fitted, :1], offsets[fitted],
                                  np.zeros((1, size * size)), band=np.ones_like(k))
            spectrum = np.fft.rfft2(mean.reshape(size, size))
            w, y = u[other], d[other]
            sw, swy = w.sum(axis=1), (w * y).sum(axis=1)
            for i, band in enumerate(bands):
                image = np.fft.irfft2(spectrum * (k <= band), s=(size, size)).ravel()
                for j, mask in enumerate(masks):
                    drawn = self._draw((image * mask)[None], offsets[other])[:, 0]
                    # each star's flux and background: 2 x 2 weighted least squares
                    sdd, sd = (w * drawn**2).sum(axis=1), (w * drawn).sum(axis=1)
                    sdy = (w * y * drawn).sum(axis=1)
                    det = np.maximum(sdd * sw - sd**2, np.finfo(float).tiny)
                    flux, level = (sdy * sw - swy * sd) / det, (sdd * swy - sd * sdy) / det
                    misfit[i, j] += (w * (y - flux[:, None] * drawn - level[:, None]) ** 2).sum()
        i, j = np.unravel_index(np.argmin(misfit), misfit.shape)
        return float(bands[i]), float(supports[j])

    def _disc(self, radius):
        """0/1 per fine sample: within ``radius`` pixels of the grid's centre."""
        f, size, _ = self._grid(self.fit_size_)
        r = np.hypot(*np.mgrid[0:size, 0:size] - (size - 1) / 2.0) / f
        return (r <= radius).ravel().astype(float)

    def _band_limited(self, fine, band=None):
        """Fine images (m, S*S) with their frequencies outside ``band`` (0/1 per frequency
        of the fine grid's ``rfft2``, default :meth:`_band`) removed."""
        size = self._grid(self.fit_size_)[1]
        band = self._band() if band is None else band
        out = np.fft.irfft2(np.fft.rfft2(fine.reshape(-1, size, size)) * band, s=(size, size))
        return out.reshape(fine.shape)
