"""Path arrays -> per-link structure: the paths of every link sorted by delay
(:class:`DiscreteCIR`) and each link's first detectable path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.errors import HallrayError


def check_paths(
    link: np.ndarray, delay_s: np.ndarray, gain: np.ndarray, n_links: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    link = np.asarray(link)
    delay_s = np.asarray(delay_s, dtype=float)
    gain = np.asarray(gain, dtype=complex)
    if isinstance(n_links, bool) or not isinstance(n_links, (int, np.integer)) or n_links < 0:
        raise HallrayError(f"n_links must be a non-negative integer, got {n_links!r}")
    if link.ndim != 1 or delay_s.shape != link.shape or gain.shape != link.shape:
        raise HallrayError(
            f"link, delay_s and gain must be 1-D of equal length, got shapes "
            f"{link.shape}, {delay_s.shape}, {gain.shape}"
        )
    if link.size and link.dtype.kind not in "iu":
        raise HallrayError(f"link must be an integer array, got dtype {link.dtype}")
    link = link.astype(np.int64)
    if link.size and (link.min() < 0 or link.max() >= n_links):
        raise HallrayError(
            f"link indices must be in [0, {n_links}), got {link.min()}..{link.max()}"
        )
    if not np.all(np.isfinite(delay_s)):
        raise HallrayError("delay_s contains NaN or infinite values")
    if not np.all(np.isfinite(gain)):
        raise HallrayError("gain contains NaN or infinite values")
    return link, delay_s, gain, int(n_links)


def _link_delay_order(link: np.ndarray, delay_s: np.ndarray) -> np.ndarray:
    """``np.lexsort((arange, delay_s, link))``: the order by link, then delay, then position
    (``(P,) int64``). The tracer's paths come sorted by link and delay
    (:meth:`raytrace.solver.paths.Paths.sorted`), and then that order is the identity: found by
    one comparison of neighbours instead of three sorts of every path (the same permutation:
    it is unique)."""
    n = link.size
    step = link[1:] - link[:-1]
    if np.all((step > 0) | ((step == 0) & (delay_s[1:] >= delay_s[:-1]))):
        return np.arange(n, dtype=np.int64)
    return np.lexsort((np.arange(n), delay_s, link)).astype(np.int64)


@dataclass(frozen=True)
class DiscreteCIR:
    """Discrete channel impulse responses of all links, paths sorted by (link, delay).

    Attributes
    ----------
    offsets : (n_links + 1,) int64
        Paths of link ``l`` are ``[offsets[l], offsets[l + 1])`` of the arrays below.
    path_index : (P,) int64
        Index of each sorted entry in the caller's path arrays.
    delay_s : (P,) float, seconds
    gain : (P,) complex
        Complex amplitude (field relative to transmitted), as given.
    """

    offsets: np.ndarray
    path_index: np.ndarray
    delay_s: np.ndarray
    gain: np.ndarray

    @property
    def n_links(self) -> int:
        return int(self.offsets.size - 1)

    def link(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Delays (s) and complex amplitudes of one link, in order of arrival."""
        lo, hi = int(self.offsets[index]), int(self.offsets[index + 1])
        return self.delay_s[lo:hi], self.gain[lo:hi]


def discrete_cir(
    link: np.ndarray, delay_s: np.ndarray, gain: np.ndarray, n_links: int
) -> DiscreteCIR:
    """Group paths per link in order of arrival: ``h_l(t) = sum_j A_j delta(t - tau_j)`` (eq. 1).

    Parameters
    ----------
    link : (P,) int
        Link index of each path, in ``[0, n_links)``.
    delay_s : (P,) float, seconds
    gain : (P,) complex
    n_links : int

    Ties in delay keep the callers' order.
    """
    link, delay_s, gain, n_links = check_paths(link, delay_s, gain, n_links)
    order = _link_delay_order(link, delay_s)
    offsets = np.searchsorted(link[order], np.arange(n_links + 1), side="left").astype(np.int64)
    return DiscreteCIR(offsets, order.astype(np.int64), delay_s[order], gain[order])


def first_detectable_path(
    link: np.ndarray, delay_s: np.ndarray, detectable: np.ndarray, n_links: int
) -> np.ndarray:
    """Index of the earliest detectable path of each link, ``(n_links,) int64``, -1 if none.

    An undetectable path is never the first arrival, however early it is. Ties in delay go to the
    lower path index.
    """
    link = np.asarray(link, dtype=np.int64)
    detectable = np.asarray(detectable, dtype=bool)
    out = np.full(int(n_links), -1, dtype=np.int64)
    idx = np.flatnonzero(detectable)
    if idx.size == 0:
        return out
    order = idx[_link_delay_order(link[idx], np.asarray(delay_s)[idx])]
    lk = link[order]
    first = np.ones(order.size, dtype=bool)
    first[1:] = lk[1:] != lk[:-1]
    out[lk[first]] = order[first]
    return out


class SharedPaths:
    """One set of paths, checked once, with what the receivers derive from the paths alone
    (the CIR, each link's first path by a rule), computed at the first receiver that asks and
    kept for the others: the receivers of one band measure the same paths every epoch.

    Parameters
    ----------
    link, delay_s, gain, n_links : the paths, as :func:`discrete_cir` takes them
    """

    def __init__(self, link: np.ndarray, delay_s: np.ndarray, gain: np.ndarray, n_links: int):
        self._source = (link, delay_s, gain, n_links)
        self.link, self.delay_s, self.gain, self.n_links = check_paths(link, delay_s, gain, n_links)
        self._cir: DiscreteCIR | None = None
        self._first: list[tuple[object, np.ndarray]] = []

    def holds(self, link: object, delay_s: object, gain: object, n_links: object) -> bool:
        """Whether these are the very arrays (the same objects) it was made from."""
        s = self._source
        return s[0] is link and s[1] is delay_s and s[2] is gain and s[3] == n_links

    @property
    def cir(self) -> DiscreteCIR:
        """:func:`discrete_cir` of the paths (its arrays are shared: read them only)."""
        if self._cir is None:
            self._cir = discrete_cir(self.link, self.delay_s, self.gain, self.n_links)
        return self._cir

    def first_path(self, rule: object, compute) -> np.ndarray:
        """``compute()`` (the (n_links,) first path of each link by ``rule``, a value compared
        with ``==``: e.g. a link budget and a band) at the first call for ``rule``; a copy."""
        for key, first in self._first:
            if key == rule:
                return first.copy()
        first = compute()
        self._first.append((rule, first))
        return first.copy()
