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
_CG_RTOL = 1e-11
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
    """``K = diag(lambda) (x) C0 + blockdiag(N_i)`` over (n, T) arrays, with its
    preconditioner ``K_t = lambda_t (C0 + diag(N_i,tt) / lambda_t)`` from factors.

    ``C0`` (n, n) the normalised signal covariance, ``lam`` (T,), ``noise`` (n, T, T) the
    frame's noise covariances, ``factors`` one lower Cholesky factor per group of targets
    (``group_of`` (T,)) of ``C0 + diag(noise_tt / lam_t)``.
    """

    def __init__(self, C0, lam, noise, factors, group_of):
        self.C0, self.lam, self.noise = C0, lam, noise
        self.factors, self.group_of = factors, group_of

    def matvec(self, V):
        """``K V`` for V of shape (n, T, r)."""
        out = np.einsum("ij,jtr->itr", self.C0, V, optimize=True) * self.lam[None, :, None]
        out += np.einsum("itu,iur->itr", self.noise, V)
        return out

    def precondition(self, V):
        out = np.empty_like(V)
        for t in range(V.shape[1]):
            L = self.factors[self.group_of[t]]
            out[:, t] = cho_solve((L, True), V[:, t], check_finite=False) / self.lam[t]
        return out

    def solve(self, B):
        """``K^-1 B`` for B of shape (n, T, r), by preconditioned conjugate gradients
        (each of the r right-hand sides on its own); returns the solution and the number
        of iterations."""
        X = self.precondition(B)
        R = B - self.matvec(X)
        Z = self.precondition(R)
        P = Z.copy()
        rz = np.einsum("itr,itr->r", R, Z)
        norm_b = np.sqrt(np.einsum("itr,itr->r", B, B))
        norm_b[norm_b == 0] = 1.0
        for it in range(_CG_MAXITER):
            if np.all(np.sqrt(np.einsum("itr,itr->r", R, R)) <= _CG_RTOL * norm_b):
                return X, it
            KP = self.matvec(P)
            pKp = np.einsum("itr,itr->r", P, KP)
            alpha = np.divide(rz, pKp, out=np.zeros_like(rz), where=pKp > 0)
            X += alpha * P
            R -= alpha * KP
            Z = self.precondition(R)
            rz_new = np.einsum("itr,itr->r", R, Z)
            beta = np.divide(rz_new, rz, out=np.zeros_like(rz), where=rz > 0)
            P = Z + beta * P
            rz = rz_new
        return X, _CG_MAXITER


def coupled_gls(system, Z, F):
    """Generalised-least-squares drift ``beta`` (q, T) and ``K^-1 (Z - F beta)`` (n, T) of
    the coupled system, and the conjugate-gradient iterations."""
    n, T = Z.shape
    q = F.shape[1]
    rhs = np.zeros((n, T, 1 + q * T))
    rhs[:, :, 0] = Z
    for t in range(T):
        rhs[:, t, 1 + t * q:1 + (t + 1) * q] = F
    sol, n_iter = system.solve(rhs)
    KiZ, KiF = sol[:, :, 0], sol[:, :, 1:]  # KiF[:, :, t*q + j]: K^-1 (e_t (x) F_j)
    # F^T K^-1 F (qT x qT) and F^T K^-1 Z, in the order (t, j)
    FKF = np.einsum("ij,itk->tjk", F, KiF).reshape(q * T, q * T)
    FKZ = np.einsum("ij,it->tj", F, KiZ).reshape(q * T)
    beta = np.linalg.solve(FKF, FKZ).reshape(T, q).T
    alpha = KiZ - np.einsum("itk,k->it", KiF, beta.T.reshape(-1))
    return beta, alpha, n_iter
