"""The mixture NLL of :func:`positioning.model.noise.mixture_nll` for every clock hypothesis of
every grid cell, compiled: the inner loop of ``nlos-map``'s grid starts
(:func:`positioning.estimators.nlos.grid_starts`).

In numpy the grid's (A, G, N, N) residuals go through some forty array passes (three
log-densities, the log-sum-exp, the responsibilities the grid does not use); here each element
is computed once, in registers. The arithmetic is numpy's, in the same order (no ``fastmath``:
no reassociation, no fused multiply-add), ``exp``/``log``/``log1p`` from the C library and
``log_ndtr`` from scipy's own scalar routine (``scipy.special.cython_special``, the function
scipy's ufunc loops over). Where numpy's ``exp`` and ``log`` are the C library's (x86-64
without AVX-512: numpy vectorises them only there), the results are numpy's bit for bit;
elsewhere they may differ in the last bits, which only the grid's comparisons (the deepest
cells) see (tests/positioning/estimators/test_mixture_kernel.py).

Compiled with the options of the tracer's kernels (:mod:`raytrace.core.jit`, which positioning
may not import): an explicit signature, ``error_model="numpy"``, no ``fastmath``, ``nogil``, and
the on-disk cache (without a writable cache directory, compiled in memory instead).
"""

from __future__ import annotations

import math
from typing import Any

import llvmlite.binding as llvm
import numba
import numpy as np
from numba import types
from numba.extending import get_cython_function_address

__all__ = ["pairwise_mixture_nll"]

# scipy's double-precision log_ndtr, called by name: a kernel that calls a symbol (not a ctypes
# pointer, a "dynamic global") can be cached on disk
llvm.add_symbol(
    "positioning_log_ndtr",
    get_cython_function_address("scipy.special.cython_special", "__pyx_fuse_1log_ndtr"),
)
_log_ndtr = types.ExternalFunction("positioning_log_ndtr", types.float64(types.float64))

_OPTIONS: dict[str, Any] = dict(cache=True, nogil=True, error_model="numpy", fastmath=False)
_SIGNATURE = (
    "void(f8[:, :, ::1], b1[:, ::1], f8[:, :, ::1], f8[:, :, :, ::1], f8, f8, f8[:, :, :, ::1])"
)


def _compile(fn: Any) -> Any:
    try:
        return numba.njit(_SIGNATURE, **_OPTIONS)(fn)
    except RuntimeError as exc:  # no cache locator (a read-only installation, no home)
        if "no locator available" not in str(exc):
            raise
        return numba.njit(_SIGNATURE, **{**_OPTIONS, "cache": False})(fn)


@numba.njit(inline="always", **_OPTIONS)
def _exp_below(v, top):
    """``exp(v - top)`` with the C library's bits, without calling it where they are known:
    1 for the top itself, 0 where the exponential underflows (below -745.2)."""
    d = v - top
    if d == 0.0:
        return 1.0
    if d < -746.0:
        return 0.0
    return math.exp(d)


@_compile
def _pairwise_kernel(s, valid, per_link, log_share, lam, half_log_2pi, out):
    """``out[a, g, j, n]``: the NLL of ``s[a, g, n] - s[a, g, j]`` for valid n and j (the other
    entries are left as they are). ``per_link`` (6, A, N): sigma, the wide component's sigma,
    their logs, the late log-density's constant and ``sigma / lam``; ``log_share`` (3, A, G, N):
    the logs of the three shares. Every expression is :mod:`positioning.model.noise`'s, in its
    order of evaluation."""
    A, G, N = s.shape
    for a in range(A):
        for n in range(N):
            if not valid[a, n]:
                continue
            sig = per_link[0, a, n]
            sw = per_link[1, a, n]
            log_sig = per_link[2, a, n]
            log_sw = per_link[3, a, n]
            late0 = per_link[4, a, n]
            sig_lam = per_link[5, a, n]
            for g in range(G):
                c0 = log_share[0, a, g, n]
                c1 = log_share[1, a, g, n]
                c2 = log_share[2, a, g, n]
                sn = s[a, g, n]
                for j in range(N):
                    if not valid[a, j]:
                        continue
                    r = sn - s[a, g, j]
                    z = r / sig
                    zw = r / sw
                    # component_logpdf: core, wide, late; plus the log shares (mixture_nll)
                    a0 = (-0.5 * (z * z) - log_sig - half_log_2pi) + c0
                    a1 = (-0.5 * (zw * zw) - log_sw - half_log_2pi) + c1
                    pre = late0 - r / lam
                    x = z - sig_lam
                    top = a0
                    if a1 > top or a1 != a1:  # numpy's maximum: a NaN wins
                        top = a1 if top == top else top
                    if x < -1.0 and top == top:
                        # log_ndtr(x) < -x^2/2 - 0.9 for x < -1 (Mills' ratio): a late term
                        # under exp(-40) of the larger one cannot change the sum, which is >= 1
                        # (adding less than half an ulp of it rounds back to it)
                        bound = (pre - 0.5 * (x * x)) + c2
                        slack = 40.0 + 1e-10 * (abs(pre) + 0.5 * (x * x) + abs(c2) + abs(top))
                        if bound < top - slack:
                            total = _exp_below(a0, top) + _exp_below(a1, top)
                            out[a, g, j, n] = -(top + math.log(total))
                            continue
                    a2 = (pre + _log_ndtr(x)) + c2
                    if a2 > top or a2 != a2:
                        top = a2 if top == top else top
                    total = (_exp_below(a0, top) + _exp_below(a1, top)) + _exp_below(a2, top)
                    out[a, g, j, n] = -(top + math.log(total))


def pairwise_mixture_nll(
    s: np.ndarray,
    valid: np.ndarray,
    sigma: np.ndarray,
    p_wide: np.ndarray,
    p_late: np.ndarray,
    s_wide: float,
    lam: float,
) -> np.ndarray:
    """(A, G, N, N) NLL of the residuals ``s[a, g, n] - s[a, g, j]`` at ``[a, g, j, n]``:
    :func:`~positioning.model.noise.mixture_nll` of ``r = s[:, :, None, :] - s[:, :, :, None]``
    with the noise core ``sigma[:, None, None, :]``; 0 where measurement n or reference j is
    not valid.

    Parameters
    ----------
    s : (A, G, N) float, metres: pseudo-range less the candidate range per epoch, cell, station
    valid : (A, N) bool, received measurements
    sigma : (A, N) float, metres: the noise core of each measurement
    p_wide, p_late : (A, G, N) float: the mixture's shares at each cell
        (:func:`~positioning.model.noise.shares`)
    s_wide : float, metres: the overlap spread
    lam : float, metres: the mean NLoS excess of the late component
    """
    A, G, N = s.shape
    sigma = np.asarray(sigma, dtype=np.float64)
    # the per-measurement terms as numpy evaluates them in component_logpdf (log of each sigma,
    # the late density's -ln lam + sigma^2 / (2 lam^2) before the residual enters)
    wide_sigma = np.sqrt(sigma**2 + s_wide**2)
    per_link = np.stack([sigma, wide_sigma, np.log(sigma), np.log(wide_sigma),
                         -np.log(lam) + sigma**2 / (2.0 * lam**2), sigma / lam])  # fmt: skip
    p_wide = np.broadcast_to(p_wide, (A, G, N))
    p_late = np.broadcast_to(p_late, (A, G, N))
    log_share = np.stack([np.log1p(-(p_wide + p_late)), np.log(p_wide), np.log(p_late)])
    out = np.zeros((A, G, N, N))
    _pairwise_kernel(np.ascontiguousarray(s, dtype=np.float64),
                     np.ascontiguousarray(valid, dtype=np.bool_), per_link, log_share,
                     float(lam), float(0.5 * np.log(2.0 * np.pi)), out)  # fmt: skip
    return out
