"""Co-Kriging with each star's noise covariance across targets (private).

Model (intrinsic coregionalisation): the targets' signal at ``x`` is ``B^(1/2) g(x)`` with
``g`` independent fields of one correlation ``C0`` (the variogram's), so that
``cov(y_i, y_j) = B C0_ij + delta_ij Sigma_i`` with ``B`` the targets' signal covariance and
``Sigma_i`` star ``i``'s noise covariance (``T x T``).

The work is done in a frame ``z = y A`` where the targets are nearly independent:
``A`` solves the generalised eigenproblem of the targets' sample covariance against the
stars' mean noise covariance (``A^T Sigma_mean A = I``, ``A^T cov(y) A`` diagonal). There
the signal covariance ``A^T B A = diag(lambda)`` is diagonal and each star's noise
``A^T Sigma_i A`` is close to diagonal (exactly when the stars' noise covariances are
proportional to one another). Hyperparameters (range, ``lambda``, ...) are fitted by
maximum likelihood on the independent targets of that frame with their marginal noise (the
off-diagonal noise of the frame left out); the Kriging system itself is solved exactly, with
the full noise covariances, by conjugate gradients preconditioned with the independent
targets' factorisations (a few iterations: the preconditioner differs from the system only
by the frame's small off-diagonal noise).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_solve, eigh

#: relative residual at which the conjugate gradients stop
_CG_RTOL = 1e-9
_CG_MAXITER = 500


def coregionalization_frame(Y, noise_cov):
    """``A`` (T, T), its inverse and each star's noise covariance in the frame (n, T, T).

    Columns of ``A`` are ordered by decreasing signal variance ``diag(A^T cov(Y) A)``.
    """
    T = Y.shape[1]
    mean_noise = noise_cov.mean(axis=0)
    mean_noise = 0.5 * (mean_noise + mean_noise.T)
    scale = np.trace(mean_noise) / T
    if not scale > 0:  # no noise: any frame (principal axes of the values)
        mean_noise, scale = np.eye(T), 1.0
    # a floor keeps the eigenproblem definite when a target has (almost) no noise
    mean_noise = mean_noise + 1e-10 * scale * np.eye(T)
    cov = np.atleast_2d(np.cov(Y, rowvar=False))
    _, A = eigh(cov, mean_noise)
    A = A[:, ::-1]
    noise_z = np.einsum("ts,itu,uv->isv", A, noise_cov, A, optimize=True)
    return A, np.linalg.inv(A), noise_z


class CoupledSystem:
    """``K = diag(lambda) (x) C0 + blockdiag(N_i)`` over (n, T) arrays and its bordered
    (generalised-least-squares) solve, preconditioned by the independent targets.

    ``C0`` (n, n) is the normalised signal covariance, ``lam`` (T,) the targets' sills,
    ``noise`` (n, T, T) the frame's noise covariances, ``factors`` the independent targets'
    ``(L, C^-1 F, (F^T C^-1 F)^-1)`` per group of targets (``group_of`` (T,)), with ``L`` the
    lower Cholesky factor of ``C0 + diag(N_i,tt / lambda_t)``, and ``F`` (n, q) the drift.
    """

    def __init__(self, C0, lam, noise, factors, group_of, F):
        self.C0, self.lam, self.noise, self.F = C0, lam, noise, F
        self.factors, self.group_of = factors, group_of

    def matvec(self, V):
        """``K V`` for V of shape (n, T)."""
        return (self.C0 @ V) * self.lam + np.einsum("itu,iu->it", self.noise, V)

    def project(self, R):
        """The independent targets' bordered solve: ``g`` with ``M g + F v = R`` and
        ``F^T g = 0`` for each target (``M = lambda C``), and ``v`` (q, T)."""
        G = np.empty_like(R)
        V = np.empty((self.F.shape[1], R.shape[1]))
        for t in range(R.shape[1]):
            L, KiF, FKiF_inv = self.factors[self.group_of[t]]
            w = cho_solve((L, True), R[:, t], check_finite=False)
            V[:, t] = FKiF_inv @ (self.F.T @ w)
            G[:, t] = (w - KiF @ V[:, t]) / self.lam[t]
        return G, V

    def solve_gls(self, Z):
        """``alpha = K^-1 (Z - F beta)`` and the generalised-least-squares ``beta`` (q, T):
        the bordered system ``K alpha + F beta = Z``, ``F^T alpha = 0``, by conjugate
        gradients projected on the constraint with the independent targets' bordered solve
        as preconditioner (Gould, Hribar & Nocedal 2001). Returns alpha, beta and the number
        of iterations."""
        alpha, _ = self.project(Z)  # the independent targets' solution
        norm = np.sqrt(max(np.vdot(Z, alpha), 1e-300))
        R = self.matvec(alpha) - Z
        G, V = self.project(R)
        R -= self.F @ V  # keep the residual off the drift's span (rounding)
        D = -G
        rg = np.vdot(R, G)
        for it in range(_CG_MAXITER):
            if not np.sqrt(abs(rg)) > _CG_RTOL * norm:
                break
            KD = self.matvec(D)
            step = rg / np.vdot(D, KD)
            alpha += step * D
            R += step * KD
            G, V = self.project(R)
            R -= self.F @ V
            rg, rg_old = np.vdot(R, G), rg
            D = -G + (rg / rg_old) * D
        else:
            it = _CG_MAXITER
        # at convergence K alpha - Z = -F beta: beta from the same projection
        _, beta = self.project(Z - self.matvec(alpha))
        return alpha, beta, it
