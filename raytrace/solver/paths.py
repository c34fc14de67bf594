"""The path container: a structure of arrays over all paths of all links.

File formats written by :meth:`Paths.save` (all carry the same fields):

* ``.npz``: every array under its attribute name, plus ``frequency_hz``, ``tx``, ``rx`` and
  ``format_version``; read back with :meth:`Paths.load`.
* ``.json``: ``{"format_version", "frequency_hz", "tx", "rx", "paths": [{...}, ...]}`` with one
  object per path (``link, tx_index, rx_index, kind, delay_s, gain_re, gain_im, power_db,
  n_reflections, n_penetrations, n_diffractions, interactions: [{"type", "point", "object"}]``).
* ``.csv``: one row per path with ``link, tx_index, rx_index, kind, delay_s, gain_re, gain_im,
  power_db, n_reflections, n_penetrations, n_diffractions`` and the interaction points as
  ``p1_x, p1_y, p1_z, ...`` (empty where a path has fewer interactions).
"""

from __future__ import annotations

import csv
import io
import json
import zipfile
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from ..core.constants import linear_power_to_db
from ..core.errors import HallrayError
from ..core.fileio import write_atomic
from ..core.memory import fresh_empty
from ..core.vec import index
from ..core.vec import rows as take_rows

#: Interaction codes in :attr:`Paths.interaction`.
NONE, REFLECTION, PENETRATION, DIFFRACTION = 0, 1, 2, 3
_LETTER = {REFLECTION: "R", PENETRATION: "T", DIFFRACTION: "D"}
_NAME = {REFLECTION: "reflection", PENETRATION: "penetration", DIFFRACTION: "diffraction"}
FORMAT_VERSION = 1


@dataclass
class Paths:
    """All paths between a set of transmitters and receivers.

    Attributes
    ----------
    tx : (T, 3) float, transmitter positions, metres
    rx : (R, 3) float, receiver positions, metres
    frequency_hz : float
    link : (P,) int, ``tx_index * R + rx_index``
    tx_index, rx_index : (P,) int
    delay_s : (P,) float, propagation delay, seconds
    gain : (P,) complex, field amplitude at the receiver relative to the transmitted one between
        isotropic, vertically polarised antennas; ``|gain|**2`` is the path's power gain
        (``(lambda / (4 pi d))**2`` for line of sight)
    n_reflections, n_penetrations, n_diffractions : (P,) int
    interaction : (P, D) int8, interaction codes in path order (0 none, 1 reflection,
        2 penetration, 3 diffraction)
    points : (P, D, 3) float, interaction points, metres (NaN padded)
    objects : (P, D) int, object index of each interaction (-1 padded)
    elements : (P, D) int, scene element of each interaction: facet index for a reflection, wedge
        index for a diffraction, -1 for a penetration and padding
    """

    tx: np.ndarray
    rx: np.ndarray
    frequency_hz: float
    link: np.ndarray
    tx_index: np.ndarray
    rx_index: np.ndarray
    delay_s: np.ndarray
    gain: np.ndarray
    n_reflections: np.ndarray
    n_penetrations: np.ndarray
    n_diffractions: np.ndarray
    interaction: np.ndarray
    points: np.ndarray
    objects: np.ndarray
    elements: np.ndarray

    #: The per-path arrays (one row per path): what concatenating, selecting and saving paths
    #: carry row by row.
    PER_PATH = (
        "link",
        "tx_index",
        "rx_index",
        "delay_s",
        "gain",
        "n_reflections",
        "n_penetrations",
        "n_diffractions",
        "interaction",
        "points",
        "objects",
        "elements",
    )

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def empty(cls, tx: np.ndarray, rx: np.ndarray, frequency_hz: float, depth: int = 0) -> Paths:
        """No paths."""
        return cls(
            tx=np.asarray(tx, dtype=float).reshape(-1, 3),
            rx=np.asarray(rx, dtype=float).reshape(-1, 3),
            frequency_hz=float(frequency_hz),
            link=np.zeros(0, np.int64),
            tx_index=np.zeros(0, np.int64),
            rx_index=np.zeros(0, np.int64),
            delay_s=np.zeros(0),
            gain=np.zeros(0, complex),
            n_reflections=np.zeros(0, np.int16),
            n_penetrations=np.zeros(0, np.int16),
            n_diffractions=np.zeros(0, np.int16),
            interaction=np.zeros((0, depth), np.int8),
            points=np.zeros((0, depth, 3)),
            objects=np.zeros((0, depth), np.int64),
            elements=np.zeros((0, depth), np.int64),
        )

    @classmethod
    def concatenate(cls, parts: list[Paths], threads: int = 1) -> Paths:
        """Join path sets of the same links, padding interaction arrays to the deepest.

        With ``threads > 1`` the copies run on that many threads (numpy copies without the GIL):
        joining millions of paths is mostly first writes to fresh memory, which the threads
        fault in side by side. The result does not depend on ``threads``.
        """
        if not parts:
            raise ValueError("nothing to concatenate")
        depth = max(p.interaction.shape[1] for p in parts)
        padded = [p._padded(depth) for p in parts]
        first = parts[0]
        if threads <= 1 or len(padded) == 1:
            kw = {k: np.concatenate([getattr(p, k) for p in padded]) for k in cls.PER_PATH}
            return cls(tx=first.tx, rx=first.rx, frequency_hz=first.frequency_hz, **kw)
        from concurrent.futures import ThreadPoolExecutor

        starts = np.concatenate([[0], np.cumsum([p.n_paths for p in padded])])
        kw = {}
        tasks = []  # (bytes, out, row, source)
        for k in cls.PER_PATH:
            src = [getattr(p, k) for p in padded]
            # small pages: huge ones may stall the first writes in compaction (core.memory)
            out = fresh_empty((int(starts[-1]), *src[0].shape[1:]), dtype=src[0].dtype)
            kw[k] = out
            tasks += [(a.nbytes, out, int(r), a) for a, r in zip(src, starts[:-1]) if len(a)]
        # biggest copies first, each to the least loaded thread
        tasks.sort(key=lambda t: -t[0])
        lanes: list[list[tuple]] = [[] for _ in range(int(threads))]
        load = [0] * len(lanes)
        for t in tasks:
            i = load.index(min(load))
            lanes[i].append(t)
            load[i] += t[0]

        def run(lane: list[tuple]) -> None:
            for _, out, row, a in lane:
                out[row : row + len(a)] = a

        with ThreadPoolExecutor(len(lanes)) as ex:
            list(ex.map(run, lanes))
        return cls(tx=first.tx, rx=first.rx, frequency_hz=first.frequency_hz, **kw)

    def _padded(self, depth: int) -> Paths:
        d = self.interaction.shape[1]
        if d == depth:
            return self
        extra = depth - d
        n = self.n_paths
        return Paths(
            **{
                **{f.name: getattr(self, f.name) for f in fields(self)},
                "interaction": np.concatenate([self.interaction, np.zeros((n, extra), np.int8)], 1),
                "points": np.concatenate([self.points, np.full((n, extra, 3), np.nan)], 1),
                "objects": np.concatenate([self.objects, np.full((n, extra), -1, np.int64)], 1),
                "elements": np.concatenate([self.elements, np.full((n, extra), -1, np.int64)], 1),
            }
        )

    def select(self, mask: np.ndarray) -> Paths:
        """The paths where ``mask`` (bool (P,), index array or slice) selects."""
        if isinstance(mask, slice):
            kw = {k: getattr(self, k)[mask] for k in self.PER_PATH}
        else:
            sel = index(mask)
            kw = {k: take_rows(getattr(self, k), sel) for k in self.PER_PATH}
        return Paths(tx=self.tx, rx=self.rx, frequency_hz=self.frequency_hz, **kw)

    def with_receivers(self, rx: np.ndarray, first: int) -> Paths:
        """The same paths as paths of a larger receiver set ``rx`` (R, 3) in which this set's
        receivers start at index ``first`` (link indices renumbered ``tx * R + rx``)."""
        rx = np.asarray(rx, dtype=float)
        rx_index = self.rx_index + int(first)
        kw = {k: getattr(self, k) for k in self.PER_PATH}
        kw.update(rx_index=rx_index, link=self.tx_index * len(rx) + rx_index)
        return Paths(tx=self.tx, rx=rx, frequency_hz=self.frequency_hz, **kw)

    def sorted(self) -> Paths:
        """Paths ordered by link, then delay, then kind, then the objects and elements they
        interact with: a total, canonical order (two distinct paths differ in one of them), so
        that the order does not depend on how the paths were found (stages, link chunks)."""
        # by delay (any sort: the order within equal delays is settled below), then stably by
        # link: as np.lexsort((delay, link)) up to that order, at a third of its cost
        order = np.argsort(self.delay_s)
        link = self.link[order]
        if len(link) and 0 <= link.min() and link.max() <= np.iinfo(np.uint16).max:
            link = link.astype(np.uint16)  # numpy sorts 16-bit keys stably by radix: 8x faster
        order = order[np.argsort(link, kind="stable")]
        # the other keys only order paths of one link with equal delays (rare): sort those
        # runs by every key (a stable sort of their rows in original order, as one lexsort of
        # everything would), whatever order the sort above left them in
        link, delay = self.link[order], self.delay_s[order]
        same = (delay[1:] == delay[:-1]) | (np.isnan(delay[1:]) & np.isnan(delay[:-1]))
        tie = (link[1:] == link[:-1]) & same
        if tie.any():
            pos = np.flatnonzero(np.concatenate([tie, [False]]) | np.concatenate([[False], tie]))
            rows = np.sort(order[pos])
            codes = self.interaction[rows].astype(np.int64)
            cols = range(codes.shape[1] - 1, -1, -1)
            ties = [self.elements[rows, i] for i in cols] + [self.objects[rows, i] for i in cols]
            keys = [codes[:, i] for i in cols]
            order[pos] = rows[np.lexsort((*ties, *keys, self.delay_s[rows], self.link[rows]))]
        return self.select(order)

    # -- derived ------------------------------------------------------------------------------
    def vertices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Reflection and diffraction vertices of every path, without penetrations.

        Returns
        -------
        kinds : (P, k) int8, interaction codes (1 reflection, 3 diffraction; 0 padding)
        points : (P, k, 3) float, metres
        elements : (P, k) int, facet or wedge index
        """
        keep = (self.interaction == REFLECTION) | (self.interaction == DIFFRACTION)
        k = int(keep.sum(axis=1).max()) if self.n_paths else 0
        # stable compaction: the kept interactions first, in path order
        order = np.argsort(~keep, axis=1, kind="stable")[:, :k]
        rows = np.arange(self.n_paths)[:, None]
        kinds = np.where(keep[rows, order], self.interaction[rows, order], 0).astype(np.int8)
        pts = self.points[rows, order]
        elem = np.where(keep[rows, order], self.elements[rows, order], -1)
        return kinds, pts, elem

    @property
    def n_paths(self) -> int:
        return int(self.delay_s.shape[0])

    @property
    def n_links(self) -> int:
        return int(len(self.tx) * len(self.rx))

    @property
    def los(self) -> np.ndarray:
        """(P,) bool, paths without any interaction."""
        return (self.interaction == NONE).all(axis=1)

    @property
    def power_db(self) -> np.ndarray:
        """(P,) float, path power gain, dB."""
        return linear_power_to_db(np.abs(self.gain) ** 2)

    @property
    def length_m(self) -> np.ndarray:
        """(P,) float, unfolded path length, metres."""
        from ..core.constants import C0

        return self.delay_s * C0

    @property
    def kind_label(self) -> np.ndarray:
        """(P,) str, the interaction sequence (``"LoS"``, ``"R"``, ``"RT"``, ``"DR"``, ...)."""
        if self.n_paths == 0:
            return np.zeros(0, dtype=str)
        # few distinct interaction sequences: label each once
        patterns, inverse = np.unique(self.interaction, axis=0, return_inverse=True)
        labels = np.array(["".join(_LETTER[int(c)] for c in row if c) or "LoS" for row in patterns])
        return labels[inverse.reshape(-1)]

    def first_arrival(self, mask: np.ndarray | None = None) -> np.ndarray:
        """Index of the earliest path of every link, -1 for links without a path.

        Parameters
        ----------
        mask : (P,) bool, optional, the paths that may count (e.g. the detectable ones)

        Returns
        -------
        (n_links,) int
        """
        ok = np.ones(self.n_paths, bool) if mask is None else np.asarray(mask, bool)
        idx = np.flatnonzero(ok)
        out = np.full(self.n_links, -1, dtype=np.int64)
        if idx.size == 0:
            return out
        order = idx[np.lexsort((self.delay_s[idx], self.link[idx]))]
        links, first = np.unique(self.link[order], return_index=True)
        out[links] = order[first]
        return out

    def strongest(self) -> np.ndarray:
        """Index of the strongest path of every link, -1 for links without a path."""
        out = np.full(self.n_links, -1, dtype=np.int64)
        if self.n_paths == 0:
            return out
        order = np.lexsort((-np.abs(self.gain), self.link))
        links, first = np.unique(self.link[order], return_index=True)
        out[links] = order[first]
        return out

    def counts_by_kind(self) -> dict[str, np.ndarray]:
        """Per-link number of paths by main mechanism: ``los``, ``reflection`` (reflections only,
        maybe penetrating), ``penetration`` (penetrations only), ``diffraction`` (any D)."""
        n = self.n_links
        los = self.los
        diff = self.n_diffractions > 0
        refl = (self.n_reflections > 0) & ~diff
        pen = (self.n_penetrations > 0) & (self.n_reflections == 0) & ~diff
        return {
            name: np.bincount(self.link[m], minlength=n)
            for name, m in (
                ("los", los),
                ("reflection", refl),
                ("penetration", pen),
                ("diffraction", diff),
            )
        }

    # -- tables -------------------------------------------------------------------------------
    def interaction_labels(self, object_names: Sequence[str] | None = None) -> np.ndarray:
        """(P,) str, each path's interactions with their objects, in path order: ``LoS``, or
        ``R(wall_north) D(machine_3)`` with ``object_names`` (``scene.object_names``), else
        ``R(#12) D(#3)`` (object indices). R reflection, T penetration, D diffraction."""
        if self.n_paths == 0:
            return np.zeros(0, dtype=str)
        names = None if object_names is None else list(object_names)
        # few distinct (sequence, objects) rows: label each once
        rows, inverse = np.unique(np.concatenate([self.interaction.astype(np.int64),
                                                  self.objects.astype(np.int64)], axis=1),
                                  axis=0, return_inverse=True)  # fmt: skip
        depth = self.interaction.shape[1]
        labels = []
        for row in rows:
            parts = []
            for code, obj in zip(row[:depth], row[depth:]):
                if code:
                    ok = names is not None and 0 <= obj < len(names)
                    parts.append(f"{_LETTER[int(code)]}({names[obj] if ok else f'#{obj}'})")
            labels.append(" ".join(parts) or "LoS")
        return np.array(labels)[inverse.reshape(-1)]

    def to_pandas(
        self,
        object_names: Sequence[str] | None = None,
        *,
        tx_names: Sequence[str] | None = None,
        rx_names: Sequence[str] | None = None,
    ) -> Any:
        """The paths as a pandas DataFrame, one row per path (pandas is an optional dependency:
        ``pip install 'hallray[pandas]'``).

        Parameters
        ----------
        object_names : sequence of str, optional, the scene's object names
            (``scene.object_names``) for the ``interactions`` column
        tx_names, rx_names : sequence of str, optional, names of the T transmitters and R
            receivers for the ``tx`` and ``rx`` columns (default: their indices)

        Returns
        -------
        pandas.DataFrame with the columns ``link, tx, rx, tx_index, rx_index`` (int, names);
        ``kind`` (``LoS``, ``R``, ``DR``, ...) and ``interactions`` (:meth:`interaction_labels`),
        str; ``delay_s``, ``excess_delay_s`` (over the straight line), seconds; ``length_m``,
        metres; ``power_db``, dB; ``gain``, complex; ``n_reflections, n_penetrations,
        n_diffractions``, int; ``first_arrival``, bool (the link's earliest path). The
        interaction points stay in :attr:`points` (row ``i`` is path ``i``).
        """
        try:
            import pandas as pd
        except ImportError:
            raise HallrayError(
                "Paths.to_pandas needs pandas, an optional dependency: "
                "pip install 'hallray[pandas]'"
            ) from None
        from ..core.constants import C0

        def names(given: Sequence[str] | None, n: int, what: str) -> np.ndarray | None:
            if given is None:
                return None
            arr = np.asarray(list(given), dtype=str)
            if len(arr) != n:
                raise HallrayError(f"{what} has {len(arr)} names for {n} positions")
            return arr

        txn = names(tx_names, len(self.tx), "tx_names")
        rxn = names(rx_names, len(self.rx), "rx_names")
        straight = np.linalg.norm(self.tx[self.tx_index] - self.rx[self.rx_index], axis=1) / C0
        first = np.zeros(self.n_paths, dtype=bool)
        f = self.first_arrival()
        first[f[f >= 0]] = True
        return pd.DataFrame({
            "link": self.link.astype(np.int64),
            "tx": self.tx_index if txn is None else txn[self.tx_index],
            "rx": self.rx_index if rxn is None else rxn[self.rx_index],
            "tx_index": self.tx_index.astype(np.int64),
            "rx_index": self.rx_index.astype(np.int64),
            "kind": self.kind_label,
            "interactions": self.interaction_labels(object_names),
            "delay_s": self.delay_s,
            "excess_delay_s": self.delay_s - straight,
            "length_m": self.length_m,
            "power_db": self.power_db,
            "gain": self.gain,
            "n_reflections": self.n_reflections.astype(np.int64),
            "n_penetrations": self.n_penetrations.astype(np.int64),
            "n_diffractions": self.n_diffractions.astype(np.int64),
            "first_arrival": first,
        })  # fmt: skip

    # -- files --------------------------------------------------------------------------------
    def save(self, path: str | Path, *, scene_sha256: str | None = None) -> None:
        """Write the paths as .npz, .json or .csv (see the module docstring), atomically;
        ``scene_sha256``: the traced scene's :meth:`~raytrace.scene.model.Scene.content_hash`,
        stored in a .npz so that a reader can refuse it for another scene
        (:func:`check_paths_scene`)."""
        p = Path(path)
        suffix = p.suffix.lower()
        if suffix == ".npz":
            buf = io.BytesIO()
            extra = {} if scene_sha256 is None else {"scene_sha256": str(scene_sha256)}
            np.savez_compressed(
                buf,
                format_version=FORMAT_VERSION,
                frequency_hz=self.frequency_hz,
                tx=self.tx,
                rx=self.rx,
                **{k: getattr(self, k) for k in self.PER_PATH},
                **extra,
            )
            data = buf.getvalue()
        elif suffix == ".json":
            data = json.dumps(self._to_json(), indent=1).encode()
        elif suffix == ".csv":
            data = self._to_csv().encode()
        else:
            raise HallrayError(
                f"unknown paths format {suffix or '(none)'!r}: use .npz, .json or .csv"
            )
        write_atomic(p, data)

    @classmethod
    def load(cls, path: str | Path) -> Paths:
        """Read paths written by :meth:`save` as .npz."""
        p = Path(path)
        if not p.exists():
            raise HallrayError(f"paths file not found: {p}")
        try:
            with np.load(p) as z:
                kw = {k: z[k] for k in cls.PER_PATH}
                paths = cls(tx=z["tx"], rx=z["rx"], frequency_hz=float(z["frequency_hz"]), **kw)
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            # a truncated or foreign file: one line, not a BadZipFile traceback
            why = " ".join(str(exc).split()) or type(exc).__name__
            raise HallrayError(
                f"cannot read paths file {p.name} (truncated or not .npz?): {why}"
            ) from None
        bad = int(np.count_nonzero(~np.isfinite(paths.delay_s)))
        if bad:
            raise HallrayError(f"paths file {p.name}: {bad} path delay(s) are NaN or infinite")
        return paths

    def _to_json(self) -> dict:
        kinds = self.kind_label
        power = self.power_db
        recs = []
        for i in range(self.n_paths):
            inter = [
                {
                    "type": _NAME[int(c)],
                    "point": [round(float(x), 9) for x in self.points[i, j]],
                    "object": int(self.objects[i, j]),
                }
                for j, c in enumerate(self.interaction[i])
                if c
            ]
            recs.append(
                {
                    "link": int(self.link[i]),
                    "tx_index": int(self.tx_index[i]),
                    "rx_index": int(self.rx_index[i]),
                    "kind": str(kinds[i]),
                    "delay_s": float(self.delay_s[i]),
                    "gain_re": float(self.gain[i].real),
                    "gain_im": float(self.gain[i].imag),
                    "power_db": float(power[i]),
                    "n_reflections": int(self.n_reflections[i]),
                    "n_penetrations": int(self.n_penetrations[i]),
                    "n_diffractions": int(self.n_diffractions[i]),
                    "interactions": inter,
                }
            )
        return {
            "format_version": FORMAT_VERSION,
            "frequency_hz": self.frequency_hz,
            "tx": self.tx.tolist(),
            "rx": self.rx.tolist(),
            "paths": recs,
        }

    def _to_csv(self) -> str:
        depth = self.interaction.shape[1]
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        head = [
            "link",
            "tx_index",
            "rx_index",
            "kind",
            "delay_s",
            "gain_re",
            "gain_im",
            "power_db",
            "n_reflections",
            "n_penetrations",
            "n_diffractions",
        ]
        for j in range(depth):
            head += [f"p{j + 1}_type", f"p{j + 1}_x", f"p{j + 1}_y", f"p{j + 1}_z"]
        w.writerow(head)
        kinds = self.kind_label
        power = self.power_db
        for i in range(self.n_paths):
            row = [
                int(self.link[i]),
                int(self.tx_index[i]),
                int(self.rx_index[i]),
                kinds[i],
                repr(float(self.delay_s[i])),
                repr(float(self.gain[i].real)),
                repr(float(self.gain[i].imag)),
                f"{power[i]:.6f}",
                int(self.n_reflections[i]),
                int(self.n_penetrations[i]),
                int(self.n_diffractions[i]),
            ]
            for j in range(depth):
                c = int(self.interaction[i, j])
                if c:
                    row += [_LETTER[c]] + [f"{x:.9f}" for x in self.points[i, j]]
                else:
                    row += ["", "", "", ""]
            w.writerow(row)
        return out.getvalue()


def check_paths_scene(name: str | Path, paths: Paths, scene: Any) -> None:
    """Refuse the paths file ``name`` (already loaded as ``paths``) for ``scene`` when it was
    traced in another one: by the scene hash it carries (``scene_sha256``, written by
    ``trace-scene -o``), else by transmitters, receivers or interaction points outside the scene
    (a file written before the hash). One-line :class:`HallrayError`."""
    try:
        with np.load(name) as z:
            stored = str(z["scene_sha256"]) if "scene_sha256" in z.files else None
    except (OSError, ValueError, zipfile.BadZipFile):
        stored = None
    if stored is not None and stored != scene.content_hash():
        raise HallrayError(
            f"paths file {name} was traced in another scene (its scene_sha256 differs from this "
            "scene's content hash): trace this scene (trace-scene SCENE -o FILE)"
        )
    lo, hi = scene.bounds
    slack = 0.01 * float(np.linalg.norm(hi - lo)) + 0.01
    inter = paths.points.reshape(-1, 3)
    allp = np.concatenate([paths.tx, paths.rx, inter[np.isfinite(inter).all(axis=1)]])
    if len(allp) and ((allp < lo - slack) | (allp > hi + slack)).any():
        raise HallrayError(f"paths file {name} does not belong to this scene (points outside it)")
