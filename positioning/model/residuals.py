"""Residual functions of a :class:`~positioning.model.problem.Problem`: what the solvers minimise.

* :func:`tdoa_model`: eq. 7, the signed range differences against one reference base station per
  epoch (the paper's LS and IRLS);
* :func:`pseudorange_model`: the reference-free pseudo-range model ``rho_n = |p - b_n| + beta``
  with the clock term ``beta`` an unknown (the robust estimators, the bounded re-solve, the
  integrity figures);
* :func:`pseudorange_residuals`: that model's residuals at given unknowns.

Each model function is ``fun(theta (A, k), idx (A,)) -> (r (A, M), J (A, M, k))``, batched over
the epochs ``idx`` (:data:`ModelFun`), which
:func:`positioning.estimators.solver.levenberg_marquardt` takes.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .problem import Problem
from .tdoa import ranges_and_units

ModelFun = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def tdoa_model(prob: Problem, ref: np.ndarray) -> tuple[ModelFun, np.ndarray]:
    """Residual function of eq. 7 with a per-epoch reference base station.

    Parameters
    ----------
    prob : Problem
    ref : (E,) int -- reference base station of each epoch

    Returns
    -------
    fun : ``fun(theta (A, dims), idx (A,)) -> (r (A, N), J (A, N, dims))`` with
        ``r_n = dd_ne - (|p - b_n| - |p - b_e|)`` (0 where missing) and ``J = d pred / d theta``.
    W : (E, N) float -- weights: 1 for received ``n != e``, else 0.
    """
    E, N = prob.rho.shape
    ar = np.arange(E)
    dd = prob.rho - prob.rho[ar, ref][:, None]
    W = (prob.valid & (np.arange(N)[None, :] != ref[:, None])).astype(float)
    dims = prob.dims

    def fun(theta: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = prob.position(theta, idx)
        R, U = ranges_and_units(p, prob.bs, dims)
        a = np.arange(idx.size)
        re = ref[idx]
        r = dd[idx] - (R - R[a, re][:, None])
        J = U - U[a, re][:, None, :]
        return np.where(np.isfinite(r), r, 0.0), J

    return fun, W


def pseudorange_model(prob: Problem) -> ModelFun:
    """Residual function of the reference-free pseudo-range model ``rho_n = |p - b_n| + beta``.

    Unknowns ``theta = (x, y[, z], beta)``, ``beta`` (m) being the common clock offset times c.
    Minimising it by least squares is the same as TDoA least squares with the correct (full)
    covariance of the differences, and it treats every base station alike.

    Returns ``fun(theta (A, dims+1), idx (A,)) -> (r (A, N), J (A, N, dims+1))`` with
    ``r = rho - |p - b_n| - beta`` (0 where missing).
    """
    dims = prob.dims

    def fun(theta: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = prob.position(theta, idx)
        R, U = ranges_and_units(p, prob.bs, dims)
        r = prob.rho[idx] - R - theta[:, dims : dims + 1]
        J = np.concatenate([U, np.ones(U.shape[:2] + (1,))], axis=2)
        return np.where(np.isfinite(r), r, 0.0), J

    return fun


def pseudorange_residuals(prob: Problem, theta: np.ndarray) -> np.ndarray:
    """(E, N) residuals ``rho_n - |p - b_n| - beta`` in metres, NaN where missing or unsolved."""
    idx = np.arange(prob.n_epochs)
    p = prob.position(theta, idx)
    R, _ = ranges_and_units(p, prob.bs, prob.dims)
    return prob.rho - R - theta[:, prob.dims][:, None]
