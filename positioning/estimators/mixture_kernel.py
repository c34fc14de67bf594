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

The same per-measurement arithmetic, with the shares of :func:`positioning.model.noise.shares`,
is EM's E-step and M-step weights (:class:`MixtureEStep`, for
:func:`positioning.estimators.nlos.em_fit`): there the values are the fixes' own numbers, so
``nlos-map`` uses it only where it gives numpy's bits (:func:`numpy_is_libm`), else numpy.

Compiled with the options of the tracer's kernels (:mod:`raytrace.core.jit`, which positioning
may not import): an explicit signature, ``error_model="numpy"``, no ``fastmath``, ``nogil``, and
the on-disk cache (without a writable cache directory, compiled in memory instead).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import llvmlite.binding as llvm
import numba
import numpy as np
from numba import types
from numba.extending import get_cython_function_address

from ..model import noise
from ..model.problem import LinkInfo
from ..model.tdoa import C0

__all__ = [
    "MixtureEStep",
    "deepest_by_numpy",
    "deepest_cells",
    "numpy_is_libm",
    "pairwise_mixture_nll",
    "share_terms",
]

# scipy's double-precision log_ndtr, called by name: a kernel that calls a symbol (not a ctypes
# pointer, a "dynamic global") can be cached on disk
llvm.add_symbol(
    "positioning_log_ndtr",
    get_cython_function_address("scipy.special.cython_special", "__pyx_fuse_1log_ndtr"),
)
_log_ndtr = types.ExternalFunction("positioning_log_ndtr", types.float64(types.float64))

_OPTIONS: dict[str, Any] = dict(cache=True, nogil=True, error_model="numpy", fastmath=False)
#: Above ln 3: the log of a sum of three terms, each at most 1 (the log-sum-exp's ``total``).
_LOG3_UP = math.log(3.0) + 1e-12
#: numpy's pairwise summation adds up to this many numbers in one block (PW_BLOCKSIZE).
_NUMPY_BLOCK = 128


def _compile(signature: str) -> Any:
    def wrap(fn: Any) -> Any:
        try:
            return numba.njit(signature, **_OPTIONS)(fn)
        except RuntimeError as exc:  # no cache locator (a read-only installation, no home)
            if "no locator available" not in str(exc):
                raise
            return numba.njit(signature, **{**_OPTIONS, "cache": False})(fn)

    return wrap


def _inline(fn: Any) -> Any:
    return numba.njit(inline="always", **_OPTIONS)(fn)


@_inline
def _exp_below(v, top):
    """``exp(v - top)`` with the C library's bits, without calling it where they are known:
    1 for the top itself, 0 where the exponential underflows (below -745.2)."""
    d = v - top
    if d == 0.0:
        return 1.0
    if d < -746.0:
        return 0.0
    return math.exp(d)


@_inline
def _terms(r, sig, sw, log_sig, log_sw, late0, sig_lam, c0, c1, lam, half_log_2pi):
    """:func:`_nll`'s first terms for one residual ``r`` (m), in mixture_nll's order of
    evaluation: the core's and the wide component's log-densities plus their log shares
    (``a0``, ``a1``), the late one's exponent ``pre`` and its ``log_ndtr`` argument ``x``."""
    z = r / sig
    zw = r / sw
    # component_logpdf: core, wide, late; plus the log shares (mixture_nll)
    a0 = (-0.5 * (z * z) - log_sig - half_log_2pi) + c0
    a1 = (-0.5 * (zw * zw) - log_sw - half_log_2pi) + c1
    return a0, a1, late0 - r / lam, z - sig_lam


@_inline
def _nll(r, sig, sw, log_sig, log_sw, late0, sig_lam, c0, c1, c2, lam, half_log_2pi):
    """The mixture NLL of one residuals ``r`` (m): :func:`~positioning.model.noise.mixture_nll`,
    every expression in its order of evaluation (``c0, c1, c2`` the logs of the shares)."""
    a0, a1, pre, x = _terms(r, sig, sw, log_sig, log_sw, late0, sig_lam, c0, c1, lam,
                            half_log_2pi)  # fmt: skip
    top = a0
    if a1 > top or a1 != a1:  # numpy's maximum: a NaN wins
        top = a1 if top == top else top
    if x < -1.0 and top == top:
        # log_ndtr(x) < -x^2/2 - 0.9 for x < -1 (Mills' ratio): a late term under exp(-40) of
        # the larger one cannot change the sum, which is >= 1 (adding less than half an ulp
        # of it rounds back to it)
        bound = (pre - 0.5 * (x * x)) + c2
        slack = 40.0 + 1e-10 * (abs(pre) + 0.5 * (x * x) + abs(c2) + abs(top))
        if bound < top - slack:
            return -(top + math.log(_exp_below(a0, top) + _exp_below(a1, top)))
    a2 = (pre + _log_ndtr(x)) + c2
    if a2 > top or a2 != a2:
        top = a2 if top == top else top
    total = (_exp_below(a0, top) + _exp_below(a1, top)) + _exp_below(a2, top)
    return -(top + math.log(total))


@_inline
def _nll_floor(r, sig, sw, log_sig, log_sw, late0, sig_lam, c0, c1, c2, lam, half_log_2pi):
    """A lower bound of :func:`_nll`'s value (its floating-point value, not only the exact
    one), without a transcendental function: ``-(max(a0, a1, u) + ln 3)`` with the core's and
    the wide component's log-densities ``a0, a1`` as :func:`_nll` computes them and ``u`` at
    least the late one's (``log_ndtr <= 0``; ``< -x^2/2`` for x < -1). Rounding is monotone, so
    every step keeps the bound."""
    a0, a1, pre, x = _terms(r, sig, sw, log_sig, log_sw, late0, sig_lam, c0, c1, lam,
                            half_log_2pi)  # fmt: skip
    if -1e4 < x < -1.0:  # scipy's log_ndtr is within far less than 0.9 of -x^2/2 - ln(-x) - 0.92
        u = (pre + (-0.5 * (x * x))) + c2
    else:
        u = pre + c2
    return -(max(a0, a1, u) + _LOG3_UP)


@_inline
def _numpy_sum(v, n):
    """``np.sum`` of ``v[:n]`` (n <= 128) as numpy adds a contiguous axis: one by one under 8
    numbers, otherwise eight running sums combined pairwise, then the rest one by one."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += v[i]
        return res
    r0, r1, r2, r3 = v[0], v[1], v[2], v[3]
    r4, r5, r6, r7 = v[4], v[5], v[6], v[7]
    i = 8
    while i < n - (n % 8):
        r0 += v[i]
        r1 += v[i + 1]
        r2 += v[i + 2]
        r3 += v[i + 3]
        r4 += v[i + 4]
        r5 += v[i + 5]
        r6 += v[i + 6]
        r7 += v[i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += v[i]
        i += 1
    return res


@_compile(
    "void(f8[:, :, ::1], b1[:, ::1], f8[:, :, ::1], f8[:, :, :, ::1], f8, f8, f8[:, :, :, ::1])"
)
def _pairwise_kernel(s, valid, per_link, log_share, lam, half_log_2pi, out):
    """``out[a, g, j, n]``: the NLL of ``s[a, g, n] - s[a, g, j]`` for valid n and j (the other
    entries are left as they are). ``per_link`` (6, A, N): sigma, the wide component's sigma,
    their logs, the late log-density's constant and ``sigma / lam``; ``log_share`` (3, A, G, N):
    the logs of the three shares."""
    A, G, N = s.shape
    for a in range(A):
        for n in range(N):
            if not valid[a, n]:
                continue
            sig, sw, log_sig = per_link[0, a, n], per_link[1, a, n], per_link[2, a, n]
            log_sw, late0, sig_lam = per_link[3, a, n], per_link[4, a, n], per_link[5, a, n]
            for g in range(G):
                c0, c1, c2 = log_share[0, a, g, n], log_share[1, a, g, n], log_share[2, a, g, n]
                sn = s[a, g, n]
                for j in range(N):
                    if valid[a, j]:
                        out[a, g, j, n] = _nll(sn - s[a, g, j], sig, sw, log_sig, log_sw, late0,
                                               sig_lam, c0, c1, c2, lam, half_log_2pi)  # fmt: skip


@_inline
def _cell_total(s, valid, per_link, log_share, lam, half_log_2pi, a, g, j, exact, terms):
    """The grid's total NLL of cell g with base station j as the clock reference (``exact``)
    or its lower bound: numpy's ``np.sum`` over n of the NLL, 0 for a station not received."""
    N = s.shape[2]
    sj = s[a, g, j]
    for n in range(N):
        if not valid[a, n]:
            terms[n] = 0.0
        elif exact:
            terms[n] = _nll(s[a, g, n] - sj, per_link[0, a, n], per_link[1, a, n],
                            per_link[2, a, n], per_link[3, a, n], per_link[4, a, n],
                            per_link[5, a, n], log_share[0, a, g, n], log_share[1, a, g, n],
                            log_share[2, a, g, n], lam, half_log_2pi)  # fmt: skip
        else:
            terms[n] = _nll_floor(s[a, g, n] - sj, per_link[0, a, n], per_link[1, a, n],
                                  per_link[2, a, n], per_link[3, a, n], per_link[4, a, n],
                                  per_link[5, a, n], log_share[0, a, g, n],
                                  log_share[1, a, g, n], log_share[2, a, g, n], lam,
                                  half_log_2pi)  # fmt: skip
    return _numpy_sum(terms, N)


@_compile(
    "i8(f8[:, :, ::1], b1[:, ::1], f8[:, :, ::1], f8[:, :, :, ::1], f8, f8, f8[:, ::1], f8, "
    "i8[:, ::1], i8[:, ::1], b1[:, ::1])"
)
def _deepest_kernel(s, valid, per_link, log_share, lam, half_log_2pi, cells, separation_m,
                    pick, ref, ok):  # fmt: skip
    """Per epoch a, the ``pick.shape[1]`` deepest cells of the grid's NLL (``pick[a]``), each
    at least ``separation_m`` from the ones taken before, their clock reference ``ref[a]``
    (the station whose residual is zero) and ``ok[a]`` (False: no cell left); numpy's argmin
    order (the lowest index among equal values). Branch and bound: a cell's exact NLL (and a
    reference's) is computed only where its lower bound :func:`_nll_floor` does not exceed the
    best exact value found, so the picks are those of the exact NLL of every cell. Returns the
    number of (cell, reference) totals computed exactly.

    long kernel: the bound, the search and the separation share the per-epoch scratch arrays;
    split into functions, each would take them all as arguments."""
    A, G, N = s.shape
    n_pick = pick.shape[1]
    terms = np.empty(N)
    floor = np.empty((G, N))
    floor_cell = np.empty(G)
    best = np.empty(G)
    best_ref = np.zeros(G, dtype=np.int64)
    done = np.zeros(G, dtype=np.bool_)
    masked = np.zeros(G, dtype=np.bool_)
    n_exact = 0
    for a in range(A):
        for g in range(G):
            m = np.inf
            for j in range(N):
                floor[g, j] = np.inf
                if valid[a, j]:
                    floor[g, j] = _cell_total(s, valid, per_link, log_share, lam, half_log_2pi,
                                              a, g, j, False, terms)  # fmt: skip
                    m = min(m, floor[g, j])
            floor_cell[g] = m
        order = np.argsort(floor_cell)
        done[:] = False
        masked[:] = False
        for k in range(n_pick):
            cur = np.inf
            cur_g = -1
            for t in range(G):
                g = order[t]
                if masked[g]:
                    continue
                if floor_cell[g] > cur:
                    break
                if not done[g]:
                    # the exact total of the references whose bound is not above the best one
                    j0 = np.argmin(floor[g])
                    bv = _cell_total(s, valid, per_link, log_share, lam, half_log_2pi, a, g,
                                     j0, True, terms)  # fmt: skip
                    bj = j0
                    n_exact += 1
                    for j in range(N):
                        if j == j0 or not valid[a, j] or floor[g, j] > bv:
                            continue
                        v = _cell_total(s, valid, per_link, log_share, lam, half_log_2pi, a, g,
                                        j, True, terms)  # fmt: skip
                        n_exact += 1
                        if v < bv or (v == bv and j < bj):
                            bv, bj = v, j
                    best[g], best_ref[g], done[g] = bv, bj, True
                if best[g] < cur or (best[g] == cur and g < cur_g):
                    cur, cur_g = best[g], g
            if cur_g < 0 or not cur < np.inf:
                break
            pick[a, k], ref[a, k], ok[a, k] = cur_g, best_ref[cur_g], True
            for g in range(G):  # np.linalg.norm of the 2D difference, as grid_starts had it
                dx = cells[g, 0] - cells[cur_g, 0]
                dy = cells[g, 1] - cells[cur_g, 1]
                if math.sqrt(dx * dx + dy * dy) < separation_m:
                    masked[g] = True
    return n_exact


@_inline
def _numpy_max(a, b):
    """``np.maximum(a, b)``: a NaN wins."""
    if b > a or b != b:
        return b if a == a else a
    return a


@_inline
def _free_space_db(dist, share_terms):
    """:func:`~positioning.model.noise.free_space_snr_db` at range ``dist`` (m)."""
    return share_terms[1] + 20.0 * math.log10(share_terms[2]
                                              / (share_terms[3] * _numpy_max(dist, 0.1)))


@_inline
def _shares_one(fs, snr, width, peak, share_terms):
    """:func:`~positioning.model.noise.shares` of one measurement whose free-space SNR at the
    candidate range is ``fs`` (dB), numpy's operations in its order: (p_wide, p_late).
    ``share_terms`` (:func:`share_terms`): has a deficit (1/0), the SNR offset, the carrier
    wavelength, 4 pi, the shares' constants."""
    p_late, p_wide = share_terms[4], share_terms[5]
    if share_terms[0] != 0.0:
        d = fs - snr
        if d != d:  # np.nan_to_num
            d = 0.0
        elif d == np.inf:
            d = 1.7976931348623157e308
        elif d == -np.inf:
            d = -1.7976931348623157e308
        s = 1.0 / (1.0 + math.exp(-(d - share_terms[8]) / share_terms[9]))
        p_late = share_terms[4] + share_terms[6] * s
        p_wide = share_terms[5] + share_terms[7] * s
    if width > share_terms[10]:
        p_late = _numpy_max(p_late, 0.5)
    if width < share_terms[11]:
        p_wide = _numpy_max(p_wide, 0.5)
    if peak < share_terms[12]:
        p_late = _numpy_max(p_late, 0.3)
    tot = p_late + p_wide
    scale = 0.95 / tot if tot > 0.95 else 1.0
    return p_wide * scale, p_late * scale


@_compile(
    "void(i8[::1], f8[:, ::1], f8[::1], f8[:, ::1], b1[:, ::1], f8[:, :, ::1], f8[:, :, ::1], "
    "f8[::1], f8, f8, f8[:, ::1], f8[:, :, ::1], f8[:, ::1])"
)
def _estep_kernel(idx, R, beta, rho, valid, reports, per_link, share_terms, lam, half_log_2pi,
                  nll, resp, r_out):  # fmt: skip
    """The E-step of epochs ``idx`` (A,) at ranges ``R`` (A, N) and clock terms ``beta`` (A,):
    the residual ``r_out``, the NLL ``nll`` (0 where not received) and the three
    responsibilities ``resp`` (3, A, N) of :func:`~positioning.model.noise.mixture_nll` with
    the shares of :func:`~positioning.model.noise.shares`. ``rho``, ``valid`` (E, N),
    ``reports`` (3, E, N: SNR, lobe width, peak ratio) and ``per_link`` (6, E, N, see
    :func:`_link_terms`) are those of every epoch."""
    A, N = R.shape
    for a in range(A):
        e = idx[a]
        for n in range(N):
            r = 0.0
            if valid[e, n]:
                r = (rho[e, n] - R[a, n]) - beta[a]
                if not math.isfinite(r):
                    r = 0.0
            r_out[a, n] = r
            fs = _free_space_db(R[a, n], share_terms) if share_terms[0] != 0.0 else 0.0
            pw, pl = _shares_one(fs, reports[0, e, n], reports[1, e, n], reports[2, e, n],
                                 share_terms)  # fmt: skip
            a0, a1, pre, x = _terms(r, per_link[0, e, n], per_link[1, e, n], per_link[2, e, n],
                                    per_link[3, e, n], per_link[4, e, n], per_link[5, e, n],
                                    math.log1p(-(pw + pl)), math.log(pw), lam,
                                    half_log_2pi)  # fmt: skip
            a2 = (pre + _log_ndtr(x)) + math.log(pl)
            top = _numpy_max(_numpy_max(a0, a1), a2)
            lse = top + math.log((_exp_below(a0, top) + _exp_below(a1, top))
                                 + _exp_below(a2, top))  # fmt: skip
            nll[a, n] = -lse if valid[e, n] else 0.0
            resp[0, a, n] = math.exp(a0 - lse)
            resp[1, a, n] = math.exp(a1 - lse)
            resp[2, a, n] = math.exp(a2 - lse)


@_compile("void(f8[:, ::1], f8[:, :, ::1], f8[:, ::1], b1[:, ::1], f8[:, ::1], f8, f8, f8, "
          "f8[:, ::1], f8[:, ::1])")  # fmt: skip
def _mstep_kernel(r, resp, sig, valid, rho, s_w2, lam, half_log_2pi, W, rho_shifted):
    """The M-step's weights ``W`` and shifted pseudo-ranges ``rho_shifted`` (A, N) from the
    E-step (residuals ``r``, responsibilities ``resp``) and the noise core ``sig``, as
    ``em_fit`` computes them in numpy (with
    :func:`~positioning.model.noise.late_mean_excess`)."""
    A, N = r.shape
    for a in range(A):
        for n in range(N):
            sg = sig[a, n]
            sg2 = sg * sg
            mu = r[a, n] - sg2 / lam
            z = mu / sg
            ratio = math.exp(((-0.5 * z) * z - half_log_2pi) - _log_ndtr(z))
            excess = _numpy_max(mu + sg * ratio, 0.0)
            w = (resp[0, a, n] / sg2 + resp[1, a, n] / (sg2 + s_w2)) + resp[2, a, n] / sg2
            shift = resp[2, a, n] / sg2 * excess / w
            W[a, n] = w if valid[a, n] else 0.0
            rho_shifted[a, n] = rho[a, n] - (shift if valid[a, n] else 0.0)


@_compile("void(f8[:, :, ::1], i8[::1], f8[:, :, ::1], f8[::1], f8[:, :, :, ::1])")
def _grid_log_shares_kernel(fs, at, reports, share_terms, out):
    """``out`` (3, A, G, N): the logs of the core, wide and late shares (:func:`_log_shares`
    of :func:`~positioning.model.noise.shares`) of epoch a at cell g, from the free-space SNR
    ``fs`` (H, G, N, dB) of the cells at the epoch's height ``at[a]`` and its ``reports``
    (3, A, N: SNR, lobe width, peak ratio)."""
    A = at.size
    G, N = fs.shape[1], fs.shape[2]
    for a in range(A):
        for g in range(G):
            for n in range(N):
                pw, pl = _shares_one(fs[at[a], g, n], reports[0, a, n], reports[1, a, n],
                                     reports[2, a, n], share_terms)  # fmt: skip
                out[0, a, g, n] = math.log1p(-(pw + pl))
                out[1, a, g, n] = math.log(pw)
                out[2, a, g, n] = math.log(pl)


def grid_log_shares(fs: np.ndarray | None, at: np.ndarray, links: LinkInfo | None,
                    G: int, N: int) -> np.ndarray:  # fmt: skip
    """(3, A, G, N) logs of the mixture's shares at the grid's cells, compiled: what
    :func:`~positioning.model.noise.shares` and the log of each give in numpy where
    :func:`numpy_is_libm`.

    Parameters
    ----------
    fs : (H, G, N) float, dB, or None: free-space SNR of each cell per device height (None:
        no deficit known, the links have no SNR offset or carrier)
    at : (A,) int, each epoch's height in ``fs``
    links : LinkInfo or None, the epochs' receiver reports ((A, N) each)
    G, N : int, cells and base stations
    """
    A = at.size
    terms = share_terms(links)
    if fs is None:
        terms[0] = 0.0
        fs = np.zeros((1, G, N))
    nan = np.full((A, N), np.nan)
    reports = np.stack([nan, nan, nan] if links is None
                       else [links.snr_db, links.lobe_width, links.peak_ratio_db])  # fmt: skip
    out = np.empty((3, A, G, N))
    _grid_log_shares_kernel(np.ascontiguousarray(fs, dtype=np.float64),
                            np.ascontiguousarray(at, dtype=np.int64),
                            np.ascontiguousarray(reports, dtype=np.float64), terms, out)
    return out


def _link_terms(sigma: np.ndarray, s_wide: float, lam: float) -> np.ndarray:
    """(6, A, N) per-measurement terms as numpy evaluates them in component_logpdf: sigma, the
    wide component's sigma, their logs, the late density's ``-ln lam + sigma^2 / (2 lam^2)``
    (before the residual enters) and ``sigma / lam``."""
    sigma = np.asarray(sigma, dtype=np.float64)
    wide_sigma = np.sqrt(sigma**2 + s_wide**2)
    return np.stack([sigma, wide_sigma, np.log(sigma), np.log(wide_sigma),
                     -np.log(lam) + sigma**2 / (2.0 * lam**2), sigma / lam])  # fmt: skip


def _log_shares(p_wide: np.ndarray, p_late: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """(3, A, G, N) logs of the core, wide and late shares, as mixture_nll takes them."""
    p_wide = np.broadcast_to(p_wide, shape)
    p_late = np.broadcast_to(p_late, shape)
    return np.stack([np.log1p(-(p_wide + p_late)), np.log(p_wide), np.log(p_late)])


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
    out = np.zeros(s.shape + s.shape[-1:])
    _pairwise_kernel(np.ascontiguousarray(s, dtype=np.float64),
                     np.ascontiguousarray(valid, dtype=np.bool_), _link_terms(sigma, s_wide, lam),
                     _log_shares(p_wide, p_late, s.shape), float(lam),
                     float(0.5 * np.log(2.0 * np.pi)), out)  # fmt: skip
    return out


def deepest_by_numpy(
    tot: np.ndarray, cells: np.ndarray, separation_m: float, n_pick: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The picks of :func:`deepest_cells` from the totals ``tot`` (A, G, N) (inf for a
    reference not received) by numpy's argmins: (pick, ref, ok), each (A, n_pick)."""
    A, G, _ = tot.shape
    jb = np.argmin(tot, axis=2)  # (A, G)
    score = np.take_along_axis(tot, jb[..., None], axis=2)[..., 0].copy()
    pick = np.zeros((A, n_pick), dtype=np.int64)
    ref = np.zeros((A, n_pick), dtype=np.int64)
    ok = np.zeros((A, n_pick), dtype=bool)
    ar = np.arange(A)
    for m in range(min(n_pick, G)):
        gi = np.argmin(score, axis=1)
        pick[:, m], ref[:, m], ok[:, m] = gi, jb[ar, gi], np.isfinite(score[ar, gi])
        near = np.linalg.norm(cells[None, :, :] - cells[gi][:, None, :], axis=2)
        score = np.where(near < separation_m, np.inf, score)
    return pick, ref, ok


def deepest_cells(
    s: np.ndarray,
    valid: np.ndarray,
    sigma: np.ndarray,
    p_wide: np.ndarray,
    p_late: np.ndarray,
    s_wide: float,
    lam: float,
    cells: np.ndarray,
    separation_m: float,
    n_pick: int,
    log_share: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Per epoch, the ``n_pick`` deepest cells of the grid's total mixture NLL, each at least
    ``separation_m`` from the ones taken before: the NLL of :func:`pairwise_mixture_nll`
    summed over n, the best reference j per cell (argmin over the received ones), then the
    cells by repeated argmin, as numpy would pick them from the whole (A, G, N, N) array, but
    with the NLL computed only where a lower bound leaves a cell or reference in contention.

    Parameters
    ----------
    s, valid, sigma, p_wide, p_late, s_wide, lam : as :func:`pairwise_mixture_nll`
    cells : (G, 2) float, metres: the grid's cells
    separation_m : float, metres
    n_pick : int
    log_share : (3, A, G, N) float, optional: the logs of the shares, if already made
        (:func:`grid_log_shares`); then ``p_wide`` and ``p_late`` are not used

    Returns
    -------
    pick : (A, n_pick) int, cell indices
    ref : (A, n_pick) int, the reference station at each pick
    ok : (A, n_pick) bool, False where no cell was left (then pick and ref mean nothing)
    n_exact : int, (epoch, cell, reference) totals computed exactly (A * G * N for numpy)
    """
    s = np.ascontiguousarray(s, dtype=np.float64)
    valid = np.ascontiguousarray(valid, dtype=np.bool_)
    A, G, N = s.shape
    n_pick = min(n_pick, G)
    per_link = _link_terms(sigma, s_wide, lam)
    if log_share is None:
        log_share = _log_shares(p_wide, p_late, s.shape)
    h = float(0.5 * np.log(2.0 * np.pi))
    # the bound's steps hold for finite numbers only; numpy's argmins for the rest (and for more
    # stations than numpy adds in one block)
    finite = (np.isfinite(s).all(axis=(1, 2)) & np.isfinite(per_link).all(axis=(0, 2))
              & np.isfinite(log_share).all(axis=(0, 2, 3)))  # fmt: skip
    fast = finite if N <= _NUMPY_BLOCK else np.zeros(A, dtype=bool)
    pick = np.zeros((A, n_pick), dtype=np.int64)
    ref = np.zeros((A, n_pick), dtype=np.int64)
    ok = np.zeros((A, n_pick), dtype=bool)
    n_exact = 0
    if fast.any():
        f = np.flatnonzero(fast) if not fast.all() else slice(None)  # (no copy when all are)
        p, r, o = pick[f], ref[f], ok[f]
        n_exact += int(_deepest_kernel(s[f], valid[f], np.ascontiguousarray(per_link[:, f]),
                                       np.ascontiguousarray(log_share[:, f]), float(lam), h,
                                       np.ascontiguousarray(cells, dtype=np.float64),
                                       float(separation_m), p, r, o))  # fmt: skip
        pick[f], ref[f], ok[f] = p, r, o
    if not fast.all():
        f = np.flatnonzero(~fast)
        nll = np.zeros((f.size, G, N, N))
        _pairwise_kernel(np.ascontiguousarray(s[f]), np.ascontiguousarray(valid[f]),
                         np.ascontiguousarray(per_link[:, f]),
                         np.ascontiguousarray(log_share[:, f]), float(lam), h, nll)  # fmt: skip
        tot = np.where(valid[f][:, None, :], np.sum(nll, axis=3), np.inf)
        pick[f], ref[f], ok[f] = deepest_by_numpy(tot, cells, separation_m, n_pick)
        n_exact += f.size * G * N
    return pick, ref, ok, n_exact


@functools.cache
def numpy_is_libm() -> bool:
    """numpy's float64 ``exp``, ``log``, ``log1p`` and ``log10`` are the C library's on this
    machine (numpy vectorises them only with AVX-512): then the compiled E-step gives numpy's
    bits, and ``nlos-map`` uses it."""
    x = np.random.default_rng(7).normal(0.0, 20.0, 4096)
    y = np.abs(x) + 1e-3
    z = -y / (1.0 + y)
    # whole arrays through numpy (its vectorised loops, where it has them), element by element
    # through the C library
    libm = lambda fn, v: np.array([fn(float(e)) for e in v])  # noqa: E731
    return bool(
        np.array_equal(np.exp(x), libm(math.exp, x))
        and np.array_equal(np.log(y), libm(math.log, y))
        and np.array_equal(np.log10(y), libm(math.log10, y))
        and np.array_equal(np.log1p(z), libm(math.log1p, z))
    )


def share_terms(links: LinkInfo | None) -> np.ndarray:
    """(13,) the constants of :func:`~positioning.model.noise.shares` for the compiled E-step:
    has a deficit (1/0), the SNR offset (dB), the carrier wavelength (m), 4 pi, P_LATE0,
    P_WIDE0, the late and wide shares' rises, DEFICIT_DB, DEFICIT_SLOPE_DB, WIDE_LOBE,
    NARROW_LOBE, WEAK_LOBE_DB."""
    deficit = (links is not None and links.snr_offset_db is not None
               and bool(links.center_frequency_hz))  # fmt: skip
    return np.array([
        1.0 if deficit else 0.0,
        float(links.snr_offset_db) if deficit else 0.0,
        C0 / float(links.center_frequency_hz) if deficit else 1.0,
        4.0 * np.pi,
        noise.P_LATE0, noise.P_WIDE0,
        noise.P_LATE_BLOCKED - noise.P_LATE0, noise.P_WIDE_BLOCKED - noise.P_WIDE0,
        noise.DEFICIT_DB, noise.DEFICIT_SLOPE_DB,
        noise.WIDE_LOBE, noise.NARROW_LOBE, noise.WEAK_LOBE_DB,
    ])  # fmt: skip


class MixtureEStep:
    """The compiled E-step and M-step weights of ``nlos-map``'s EM
    (:func:`positioning.estimators.nlos.em_fit`) on one problem's epochs: the per-measurement
    constants (noise core, its logs, the receiver reports) made once, not per iteration.

    Parameters
    ----------
    rho : (E, N) float, metres; valid : (E, N) bool
    links : LinkInfo or None, the receiver reports
    sigma : (E, N) float, metres: the noise core (:func:`~positioning.model.noise.link_sigma`)
    s_wide : float, metres: the overlap spread; lam : float, metres: the mean NLoS excess
    """

    def __init__(self, rho: np.ndarray, valid: np.ndarray, links: LinkInfo | None,
                 sigma: np.ndarray, s_wide: float, lam: float) -> None:  # fmt: skip
        self.rho = np.ascontiguousarray(rho, dtype=np.float64)
        self.valid = np.ascontiguousarray(valid, dtype=np.bool_)
        nan = np.full(self.rho.shape, np.nan)
        self.reports = np.ascontiguousarray(np.stack(
            [nan, nan, nan] if links is None
            else [links.snr_db, links.lobe_width, links.peak_ratio_db]), dtype=np.float64)  # fmt: skip
        self.sigma = np.ascontiguousarray(sigma, dtype=np.float64)
        self.per_link = np.ascontiguousarray(_link_terms(self.sigma, s_wide, lam))
        self.terms = share_terms(links)
        self.s_w2 = s_wide**2
        self.lam = float(lam)
        self.h = float(0.5 * np.log(2.0 * np.pi))

    def at(self, idx: np.ndarray, R: np.ndarray, beta: np.ndarray):
        """NLL (A, N) (0 where not received), responsibilities (3, A, N) and residuals (A, N)
        of epochs ``idx`` (A,) at ranges ``R`` (A, N, metres) and clock terms ``beta`` (A,)."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        A, N = idx.size, self.rho.shape[1]
        nll, resp, r = np.empty((A, N)), np.empty((3, A, N)), np.empty((A, N))
        _estep_kernel(idx, np.ascontiguousarray(R, dtype=np.float64),
                      np.ascontiguousarray(beta, dtype=np.float64), self.rho, self.valid,
                      self.reports, self.per_link, self.terms, self.lam, self.h, nll, resp,
                      r)  # fmt: skip
        return nll, resp, r

    def weights(self, idx: np.ndarray, r: np.ndarray, resp: np.ndarray):
        """The M-step's weights (A, N) (0 where not received) and pseudo-ranges less the
        expected NLoS excess (A, N, metres) of epochs ``idx`` from their E-step."""
        idx = np.asarray(idx)
        A, N = idx.size, self.rho.shape[1]
        W, rho_shifted = np.empty((A, N)), np.empty((A, N))
        _mstep_kernel(np.ascontiguousarray(r, dtype=np.float64),
                      np.ascontiguousarray(resp, dtype=np.float64),
                      np.ascontiguousarray(self.sigma[idx]), np.ascontiguousarray(self.valid[idx]),
                      np.ascontiguousarray(self.rho[idx]), self.s_w2, self.lam, self.h, W,
                      rho_shifted)  # fmt: skip
        return W, rho_shifted
