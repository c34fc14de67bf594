"""The fingerprint map: per grid cell and base station, what a digital twin predicts a receiver sees.

``accuracy-map`` (in :mod:`raytrace`) writes it; the ``twin`` estimator reads it. The file is the
whole interface between the two, so :mod:`positioning` never imports the tracer. It is one ``.npz``
(no pickles) with the keys of :data:`ARRAYS` plus ``schema``, ``schema_version`` and ``meta_json``,
checked on load: a wrong schema name or version, a missing key or an inconsistent shape is refused
with a one-line :class:`PositioningError`.

Schema ``hallray-accuracy-map``, version 1 (N cells, B base stations, M methods):

===================== ============ ===========================================================
key                   shape, dtype meaning (SI units)
===================== ============ ===========================================================
``cell_xyz``          (N, 3) f8    cell centre, metres (z = device height)
``bs_xyz``            (B, 3) f8    base-station positions, metres
``bs_names``          (B,) str     base-station names
``los``               (N, B) bool  line of sight between cell and base station
``first_kind``        (N, B) str   mechanism of the first-arriving path (``LoS``, ``R``, ``D``,
                                   ``T``, ``RD``, ...; ``""`` when no path is received)
``excess_m``          (N, B) f8    first-arrival delay x c minus the straight distance, metres
                                   (NaN when no path)
``toa_s``             (N, B) f8    predicted first-arrival ToA of the map's receiver without
                                   noise or clock offset (propagation delay), seconds; NaN when
                                   not detected
``toa_std_s``         (N, B) f8    standard deviation of the receiver's ToA over noise draws, s
``detected_fraction`` (N, B) f8    share of noise draws in which the receiver detected a path
``gdop``              (N,) f8      geometric dilution of precision of the TDoA fix (2D)
``methods``           (M,) str     positioning methods evaluated on noise draws
``err_p90_m``         (M, N) f8    p90 of the 2D error over the draws, metres
``err_mean_m``        (M, N) f8    mean 2D error over the draws, metres
``availability``      (M, N) f8    share of draws with a solved fix
===================== ============ ===========================================================

``meta_json`` holds a JSON object; the writer records at least ``band``, ``frequency_hz``,
``bandwidth_hz``, ``receiver``, ``step_m``, ``height_m``, ``scene``, ``draws`` and, when the scene
has one, ``service_area`` (a list of ``[x, y]`` vertices).

Schema version 2 adds the K strongest paths per cell and base station, so that the twin can move
them to a position inside the cell and re-run the receiver (:mod:`positioning.twin.lobe`) instead of
interpolating its ToA (K paths, fewer padded):

===================== =============== ========================================================
key                   shape, dtype    meaning (SI units)
===================== =============== ========================================================
``path_delay_s``      (N, B, K) f8    path delay, s (NaN: no path)
``path_gain``         (N, B, K) c     complex field gain relative to transmitted, isotropic
                                      antennas (0: no path)
``path_dir``          (N, B, K, 3) f  unit vector of the path's last segment, from its last
                                      interaction (or the base station) to the cell
``path_radius_m``     (N, B, K) f     wavefront radius at the cell, m: unfolded length (image
                                      source) for line of sight, reflections and
                                      penetrations, distance to the last diffraction point for
                                      diffracted paths
===================== =============== ========================================================

and ``meta["receiver_model"]``, the settings of :class:`positioning.twin.lobe.LobeReceiver` (the
noiseless first-lobe receiver the map's ``toa_s`` came from). Version 1 maps are read as before
(no paths); :func:`write_map` writes version 2 when the map has paths, else version 1.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hallray import strict_json
from hallray.safe_output import write_file

from ..errors import PositioningError

SCHEMA = "hallray-accuracy-map"
SCHEMA_VERSION = 2
#: Versions :func:`read_map` reads.
READ_VERSIONS = (1, 2)

#: Array keys of schema version 1 and their (shape pattern, kind): ``N`` cells, ``B`` base
#: stations, ``M`` methods; kinds are numpy ``dtype.kind`` letters accepted for the key.
ARRAYS: dict[str, tuple[tuple[str | int, ...], str]] = {
    "cell_xyz": (("N", 3), "f"),
    "bs_xyz": (("B", 3), "f"),
    "bs_names": (("B",), "U"),
    "los": (("N", "B"), "b"),
    "first_kind": (("N", "B"), "U"),
    "excess_m": (("N", "B"), "f"),
    "toa_s": (("N", "B"), "f"),
    "toa_std_s": (("N", "B"), "f"),
    "detected_fraction": (("N", "B"), "f"),
    "gdop": (("N",), "f"),
    "methods": (("M",), "U"),
    "err_p90_m": (("M", "N"), "f"),
    "err_mean_m": (("M", "N"), "f"),
    "availability": (("M", "N"), "f"),
}

#: Array keys added by schema version 2 (``K`` paths per cell and base station).
PATH_ARRAYS: dict[str, tuple[tuple[str | int, ...], str]] = {
    "path_delay_s": (("N", "B", "K"), "f"),
    "path_gain": (("N", "B", "K"), "c"),
    "path_dir": (("N", "B", "K", 3), "f"),
    "path_radius_m": (("N", "B", "K"), "f"),
}


@dataclass(frozen=True)
class FingerprintMap:
    """A loaded fingerprint map (see the module docstring for each field's shape and unit)."""

    cell_xyz: np.ndarray
    bs_xyz: np.ndarray
    bs_names: np.ndarray
    los: np.ndarray
    first_kind: np.ndarray
    excess_m: np.ndarray
    toa_s: np.ndarray
    toa_std_s: np.ndarray
    detected_fraction: np.ndarray
    gdop: np.ndarray
    methods: np.ndarray
    err_p90_m: np.ndarray
    err_mean_m: np.ndarray
    availability: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)
    path_delay_s: np.ndarray | None = None
    path_gain: np.ndarray | None = None
    path_dir: np.ndarray | None = None
    path_radius_m: np.ndarray | None = None

    def __post_init__(self) -> None:
        _check_arrays({k: getattr(self, k) for k in ARRAYS}, "fingerprint map")
        have = [getattr(self, k) is not None for k in PATH_ARRAYS]
        if any(have):
            _check_paths(self.arrays(), self.meta, "fingerprint map")

    @property
    def has_paths(self) -> bool:
        """True for a map with paths (schema version 2)."""
        return self.path_delay_s is not None

    @property
    def version(self) -> int:
        """The schema version this map is written with."""
        return 2 if self.has_paths else 1

    @property
    def n_cells(self) -> int:
        """Number of grid cells N."""
        return int(self.cell_xyz.shape[0])

    @property
    def n_bs(self) -> int:
        """Number of base stations B."""
        return int(self.bs_xyz.shape[0])

    def n_los(self) -> np.ndarray:
        """(N,) int: base stations in line of sight per cell."""
        return np.count_nonzero(self.los, axis=1)

    def arrays(self) -> dict[str, np.ndarray]:
        """The schema's arrays by key (no copies), with the path arrays of version 2."""
        out = {k: getattr(self, k) for k in ARRAYS}
        if self.has_paths:
            out.update({k: getattr(self, k) for k in PATH_ARRAYS})
        return out

    def select(self, keep: np.ndarray) -> FingerprintMap:
        """The map reduced to the cells ``keep`` ((N,) bool or indices)."""
        per_method = ("err_p90_m", "err_mean_m", "availability")
        out = {}
        for k, v in self.arrays().items():
            if k in per_method:
                out[k] = v[:, keep]
            elif k in ("bs_xyz", "bs_names", "methods"):
                out[k] = v
            else:
                out[k] = v[keep]
        return FingerprintMap(**out, meta=self.meta)


def _check_paths(arrays: dict[str, Any], meta: dict[str, Any], what: str) -> None:
    """Version 2: every path array present, shapes consistent, a usable receiver model."""
    from .lobe import LobeReceiver

    missing = [k for k in PATH_ARRAYS if arrays.get(k) is None]
    if missing:
        raise PositioningError(f"{what}: schema version 2 needs array {missing[0]!r}")
    sizes = {"N": np.asarray(arrays["cell_xyz"]).shape[0], "B": np.asarray(arrays["bs_xyz"]).shape[0]}
    _check_arrays(arrays, what, PATH_ARRAYS, sizes)
    if not np.isfinite(arrays["path_dir"][np.isfinite(arrays["path_delay_s"])]).all():
        raise PositioningError(f"{what}: non-finite direction of a stored path")
    try:
        LobeReceiver.from_meta(meta.get("receiver_model"))
    except PositioningError as exc:
        raise PositioningError(f"{what}: {exc}") from None


def _check_arrays(
    arrays: dict[str, np.ndarray],
    what: str,
    spec: dict[str, tuple[tuple[str | int, ...], str]] | None = None,
    sizes: dict[str, int] | None = None,
) -> None:
    version_1 = spec is None
    spec = ARRAYS if spec is None else spec
    sizes = {} if sizes is None else dict(sizes)
    for key, (pattern, kind) in spec.items():
        if key not in arrays:
            raise PositioningError(f"{what}: missing array {key!r}")
        arr = np.asarray(arrays[key])
        if arr.dtype.kind not in kind and not (kind == "f" and arr.dtype.kind in "iu"):
            raise PositioningError(f"{what}: {key!r} has dtype {arr.dtype}, expected kind {kind!r}")
        if arr.ndim != len(pattern):
            raise PositioningError(
                f"{what}: {key!r} has {arr.ndim} dimensions, expected {len(pattern)}"
            )
        for dim, want in zip(arr.shape, pattern, strict=True):
            if isinstance(want, int):
                if dim != want:
                    raise PositioningError(
                        f"{what}: {key!r} has shape {arr.shape}, expected {pattern}"
                    )
            elif sizes.setdefault(want, dim) != dim:
                raise PositioningError(
                    f"{what}: {key!r} has shape {arr.shape}, but {want} = {sizes[want]} elsewhere"
                )
    if not version_1:
        return
    if sizes.get("N", 0) == 0 or sizes.get("B", 0) == 0:
        raise PositioningError(f"{what}: no cells or no base stations")
    if not (np.isfinite(arrays["cell_xyz"]).all() and np.isfinite(arrays["bs_xyz"]).all()):
        raise PositioningError(f"{what}: non-finite cell or base-station coordinates")


def write_map(path: str | Path, fmap: FingerprintMap) -> Path:
    """Write ``fmap`` to ``path`` (``.npz``) through the one safe output layer
    (:func:`hallray.safe_output.write_file`: temporary file in the folder, then rename; symlinks
    followed, special files refused, umask respected).

    Returns the path written. The file loads with :func:`read_map` and ``numpy.load`` without
    pickles.
    """
    path = Path(path)
    payload = {k: np.asarray(v) for k, v in fmap.arrays().items()}
    payload["schema"] = np.array(SCHEMA)
    payload["schema_version"] = np.array(fmap.version)
    payload["meta_json"] = np.array(json.dumps(fmap.meta, sort_keys=True, default=_jsonable))
    write_file(path, lambda fh: np.savez_compressed(fh, **payload), what="map")
    return path


def read_map(path: str | Path) -> FingerprintMap:
    """Load and check a fingerprint map written by ``accuracy-map``.

    Raises
    ------
    PositioningError
        One line naming the problem: unreadable or corrupt file, another schema or version,
        a missing key, a wrong shape or dtype.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise PositioningError(f"{path}: no such map file") from None
    except (OSError, ValueError, EOFError) as exc:
        raise PositioningError(f"{path}: not a readable .npz map ({exc})") from None
    except Exception as exc:  # zipfile.BadZipFile and friends from a truncated file
        raise PositioningError(f"{path}: corrupt map file ({type(exc).__name__})") from None
    schema = str(data.get("schema", ""))
    if schema != SCHEMA:
        raise PositioningError(f"{path}: not a {SCHEMA} file (schema {schema!r})")
    try:
        version = int(data.get("schema_version", -1))
    except (TypeError, ValueError):
        version = -1
    if version not in READ_VERSIONS:
        raise PositioningError(
            f"{path}: {SCHEMA} schema version {version} is not supported (this reader: "
            f"{', '.join(map(str, READ_VERSIONS))})"
        )
    try:
        meta = strict_json.loads(str(data.get("meta_json", "{}")))
    except ValueError as exc:  # not JSON, or a key given twice
        raise PositioningError(f"{path}: meta_json is not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise PositioningError(f"{path}: meta_json is not a JSON object")
    _check_arrays(data, str(path))
    keys = list(ARRAYS)
    if version == 2:
        _check_paths(data, meta, str(path))
        keys += list(PATH_ARRAYS)
    return FingerprintMap(**{k: data[k] for k in keys}, meta=meta)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")
