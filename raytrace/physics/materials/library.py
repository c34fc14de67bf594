"""Building materials: the ITU-R P.2040-3 power-law model (:class:`Material`), the library of
named materials with a scene's object binding (:class:`MaterialLibrary`, built from
:data:`~raytrace.physics.materials.table.ITU_TABLE` and extended by a material YAML), and the
complex permittivity of a named material (:func:`permittivity`). Conventions:
:mod:`raytrace.physics.materials`.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from hallray.errors import brief

from ...core.constants import EPS0
from ...core.errors import MaterialError
from ...core.fileio import read_yaml
from .table import ITU_TABLE, P2040_SOURCE

__all__ = ["DEFAULT_USER_THICKNESS_M", "ExtrapolationWarning", "Material", "MaterialLibrary",
           "permittivity"]


#: Slab thickness given to a user material whose YAML entry has no ``thickness``, m.
DEFAULT_USER_THICKNESS_M = 0.01


#: Relative slack on the valid-range test, so that e.g. exactly 1 GHz is in a 1-100 GHz range.
_RANGE_RTOL = 1e-9


_GHZ = 1e9


class ExtrapolationWarning(UserWarning):
    """A material model is evaluated outside its valid frequency range (``extrapolate=True``)."""


def _fmt_ghz(value_hz: float) -> str:
    """Frequency in GHz for messages: ``3.775``, ``0.001``, ``inf``."""
    if math.isinf(value_hz):
        return "inf"
    return f"{value_hz / _GHZ:.6g}"


_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")


def _canonical(name: str) -> str:
    """Canonical material name: lower case, ``-`` and blanks turned into ``_``."""
    return re.sub(r"[\s\-]+", "_", str(name).strip().lower())


@dataclass(frozen=True)
class Material:
    """One material: the ITU-R P.2040-3 section 2.1.4 power-law model and a default slab thickness.

    ``eta' = a f^b`` and ``sigma = c f^d`` (S/m) with ``f`` in GHz, valid for
    ``f_min_hz <= f <= f_max_hz``.

    Parameters
    ----------
    name : str
        Canonical name (lower case, ``[a-z][a-z0-9_]*``).
    a, b : float
        Real relative permittivity ``eta' = a f_GHz^b`` (``a > 0``).
    c, d : float
        Conductivity ``sigma = c f_GHz^d`` in S/m (``c >= 0``).
    f_min_hz, f_max_hz : float, Hz
        Valid frequency range of the model (``f_max_hz`` may be ``inf``).
    thickness_m : float, m
        Default slab thickness, used for open sheets (single-surface meshes) whose thickness the
        geometry does not give. A default only: users override it in the material YAML.
    source : str
        Where the entry comes from (``"ITU-R P.2040-3 Table 3"`` or the YAML file), for messages.
    """

    name: str
    a: float
    b: float
    c: float
    d: float
    f_min_hz: float
    f_max_hz: float
    thickness_m: float
    source: str = "user"

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not _NAME_RE.match(self.name):
            raise MaterialError(
                f"bad material name {brief(self.name)}: use letters, digits and '_', starting with a letter"
            )
        for key in ("a", "b", "c", "d", "f_min_hz", "f_max_hz", "thickness_m"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)):
                raise MaterialError(
                    f"material '{self.name}': {key} must be a number, got {brief(value)}"
                )
            object.__setattr__(self, key, float(value))
        n = self.name
        if not (math.isfinite(self.a) and self.a > 0):
            raise MaterialError(f"material '{n}': eta' coefficient a must be > 0, got {self.a}")
        if not (math.isfinite(self.c) and self.c >= 0):
            raise MaterialError(f"material '{n}': sigma coefficient c must be >= 0, got {self.c}")
        if not (math.isfinite(self.b) and math.isfinite(self.d)):
            raise MaterialError(f"material '{n}': exponents b, d must be finite")
        if not (0 <= self.f_min_hz < self.f_max_hz) or math.isnan(self.f_max_hz):
            raise MaterialError(
                f"material '{n}': bad frequency range {self.f_min_hz} - {self.f_max_hz} Hz"
            )
        if not (math.isfinite(self.thickness_m) and self.thickness_m > 0):
            raise MaterialError(f"material '{n}': thickness must be > 0 m, got {self.thickness_m}")
        self._check_passive()

    def _check_passive(self) -> None:
        """A passive material's relative permittivity has a real part >= 1 (vacuum's): check
        eta' = a f^b at the ends of the valid range (a power law is monotonic between them)."""
        ends = [f for f in (self.f_min_hz, self.f_max_hz) if 0 < f < math.inf] or [1e9]
        for f_hz in ends if self.b != 0 else [1e9]:
            eta = self.a * (f_hz / 1e9) ** self.b
            if eta < 1.0 - 1e-9:
                at = f" at {_fmt_ghz(f_hz)} GHz" if self.b != 0 else ""
                raise MaterialError(
                    f"material '{self.name}': eta_real (relative permittivity, real part) is "
                    f"{eta:.4g}{at}; a physical material has eta_real >= 1"
                )

    @property
    def range_text(self) -> str:
        """Valid range for messages, e.g. ``"1-100 GHz"``."""
        return f"{_fmt_ghz(self.f_min_hz)}-{_fmt_ghz(self.f_max_hz)} GHz"

    def _check_frequency(self, f: np.ndarray, extrapolate: bool, stacklevel: int = 4) -> None:
        if f.ndim == 0 and self.f_min_hz * (1.0 - _RANGE_RTOL) <= float(f) <= self.f_max_hz * (
            1.0 + _RANGE_RTOL
        ):
            return  # one frequency in range (every trace asks per material): no array work
        if f.size == 0:
            return
        flat = np.ravel(f)
        bad_f = ~(np.isfinite(flat) & (flat > 0))
        if np.any(bad_f):
            raise MaterialError(
                f"material '{self.name}': frequency must be positive and finite, "
                f"got {flat[bad_f][0]} Hz"
            )
        lo = self.f_min_hz * (1.0 - _RANGE_RTOL)
        hi = self.f_max_hz * (1.0 + _RANGE_RTOL)
        outside = (f < lo) | (f > hi)
        if not np.any(outside):
            return
        bad = float(np.ravel(f)[np.argmax(np.ravel(outside))])
        where = f"material '{self.name}' ({self.source}) is valid for {self.range_text}"
        if not extrapolate:
            raise MaterialError(
                f"{where}, not {_fmt_ghz(bad)} GHz; to evaluate it there anyway, allow "
                "extrapolation (--extrapolate; extrapolate: true in a sweep config; "
                "extrapolate=True in Python)"
            )
        warnings.warn(
            f"{where}; extrapolating to {_fmt_ghz(bad)} GHz",
            ExtrapolationWarning,
            stacklevel=stacklevel,
        )

    def properties(
        self, frequency_hz: float | np.ndarray, extrapolate: bool = False
    ) -> tuple[Any, Any]:
        """Real relative permittivity and conductivity (P.2040-3 section 2.1.4, Table 3).

        Parameters
        ----------
        frequency_hz : float or (...) float array, Hz
        extrapolate : bool
            Outside ``[f_min_hz, f_max_hz]``: ``False`` raises :class:`MaterialError`, ``True``
            evaluates the power law anyway and warns with :class:`ExtrapolationWarning`.

        Returns
        -------
        eta_real : float or (...) float, dimensionless
        sigma : float or (...) float, S/m
        """
        f = np.asarray(frequency_hz, dtype=float)
        self._check_frequency(f, extrapolate, stacklevel=3)
        f_ghz = f / _GHZ
        eta_real = self.a * f_ghz**self.b
        sigma = self.c * f_ghz**self.d
        if f.ndim == 0:
            return float(eta_real), float(sigma)
        return eta_real, sigma

    def permittivity(
        self, frequency_hz: float | np.ndarray, extrapolate: bool = False
    ) -> complex | np.ndarray:
        """Complex relative permittivity ``eta' - j sigma / (2 pi f eps0)`` (P.2040-3 eq. 9b).

        Parameters
        ----------
        frequency_hz : float or (...) float array, Hz
        extrapolate : bool
            See :meth:`properties`.

        Returns
        -------
        eta : complex, or (...) complex128 array for array input; ``Im(eta) <= 0``.
        """
        return self._permittivity(frequency_hz, extrapolate, stacklevel=4)

    def permittivity_slope(
        self, frequency_hz: float | np.ndarray, extrapolate: bool = False
    ) -> complex | np.ndarray:
        """``f d eta / d f`` of the power-law model, for group delays
        (:func:`~raytrace.physics.materials.slab_group_delay`).

        ``eta' = a f^b`` gives ``b eta'``; ``eta'' = sigma / (2 pi f eps0)`` with ``sigma = c f^d``
        gives ``(d - 1) eta''``: ``f d eta / d f = b eta' - j (d - 1) eta''``.
        """
        eta = self._permittivity(frequency_hz, extrapolate, stacklevel=4)
        return self.b * np.real(eta) + 1j * (self.d - 1.0) * np.imag(eta)

    def _permittivity(
        self, frequency_hz: float | np.ndarray, extrapolate: bool, stacklevel: int
    ) -> complex | np.ndarray:
        f = np.asarray(frequency_hz, dtype=float)
        self._check_frequency(f, extrapolate, stacklevel=stacklevel)
        f_ghz = f / _GHZ
        eta = self.a * f_ghz**self.b - 1j * (self.c * f_ghz**self.d) / (2.0 * np.pi * f * EPS0)
        if f.ndim == 0:
            return complex(eta)
        return eta


_ELECTRICAL_KEYS = frozenset({"eta_real", "sigma", "a", "b", "c", "d", "f_range_ghz"})


_MATERIAL_KEYS = _ELECTRICAL_KEYS | {"thickness"}


_TOP_KEYS = ("materials", "bind", "default")


def _number(origin: str, name: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MaterialError(f"{origin}: material '{name}': {key} must be a number, got {brief(value)}")
    value = float(value)
    if math.isnan(value):
        raise MaterialError(f"{origin}: material '{name}': {key} is NaN")
    return value


class MaterialLibrary(Mapping[str, Material]):
    """Immutable mapping ``name -> Material`` plus the object binding of a material YAML.

    Build with :meth:`itu` (the P.2040-3 table) and extend with :meth:`with_yaml`, which returns a
    new library. Look-ups are case-insensitive, treat ``-`` like ``_`` and accept an ``itu_`` prefix
    (``"ITU_Concrete"`` -> ``concrete``).

    Attributes
    ----------
    bind : dict[str, str]
        Glob pattern on object names -> material name (``{"forklift_*": "metal"}``), for the scene
        loader; every value is a material of this library.
    default : str or None
        Material for objects neither bound nor matched by name (scene loader's choice to use it).
    """

    def __init__(
        self,
        materials: Mapping[str, Material] | None = None,
        bind: Mapping[str, str] | None = None,
        default: str | None = None,
    ) -> None:
        self._materials: dict[str, Material] = {}
        for key, mat in (materials or {}).items():
            if not isinstance(mat, Material):
                raise MaterialError(f"library entry {brief(key)} is not a Material")
            if _canonical(key) != mat.name:
                raise MaterialError(f"library key {brief(key)} differs from material name {brief(mat.name)}")
            self._materials[mat.name] = mat
        self.bind: dict[str, str] = {str(k): self._resolve(v) for k, v in (bind or {}).items()}
        self.default: str | None = None if default is None else self._resolve(default)

    # -- construction ---------------------------------------------------------------------------
    @classmethod
    def itu(cls) -> MaterialLibrary:
        """The 14 materials of ITU-R P.2040-3 Table 3 with default thicknesses."""
        mats = {
            row[0]: Material(*row, source=P2040_SOURCE)  # type: ignore[arg-type]
            for row in ITU_TABLE
        }
        return cls(mats)

    def with_yaml(self, source: str | os.PathLike[str] | Mapping[str, Any]) -> MaterialLibrary:
        """New library with the user materials, overrides, ``bind`` and ``default`` of a YAML.

        Parameters
        ----------
        source : path to a YAML file, or the already parsed mapping
            Top-level keys ``materials``, ``bind``, ``default`` (all optional). Each material is
            ``{eta_real, sigma[, f_range_ghz][, thickness]}`` (frequency-independent) or
            ``{a, b, c, d, f_range_ghz[, thickness]}`` (P.2040 power law); an existing name with only
            ``thickness`` overrides that entry's thickness, an existing name with electrical
            parameters replaces the entry. ``bind`` is merged into this library's binding; ``default``
            replaces this library's default when given.

        Raises
        ------
        MaterialError
            Missing or unparsable file, unknown keys, bad or missing values, unknown material names.
        """
        data, origin = _load_yaml(source)
        unknown = sorted(set(data) - set(_TOP_KEYS))
        if unknown:
            raise MaterialError(
                f"{origin}: unknown top-level key(s) {', '.join(map(str, unknown))} "
                f"(allowed: {', '.join(_TOP_KEYS)})"
            )
        mats = dict(self._materials)
        entries = data.get("materials") or {}
        if not isinstance(entries, Mapping):
            raise MaterialError(f"{origin}: 'materials' must be a mapping name -> properties")
        spelled: dict[str, str] = {}  # canonical name -> the spelling of this file
        for raw_name, spec in entries.items():
            name = _canonical(raw_name)
            if name not in mats and name.startswith("itu_") and name[4:] in mats:
                name = name[4:]
            if name in spelled:  # Concrete and concrete: one material, given twice
                raise MaterialError(
                    f"{origin}: materials {brief(spelled[name])} and {brief(raw_name)} are one "
                    f"material ({name}; names ignore case, '-' and blanks): give it once"
                )
            spelled[name] = str(raw_name)
            mats[name] = _material_from_spec(origin, name, spec, mats.get(name))
        bind_in = data.get("bind") or {}
        if not isinstance(bind_in, Mapping):
            raise MaterialError(f"{origin}: 'bind' must be a mapping glob -> material name")
        bind = dict(self.bind)
        lib = MaterialLibrary(mats)
        for pattern, target in bind_in.items():
            if not isinstance(pattern, str) or not pattern:
                raise MaterialError(
                    f"{origin}: bind pattern {brief(pattern)} must be a non-empty string"
                )
            if not isinstance(target, str):
                raise MaterialError(f"{origin}: bind '{pattern}': material must be a name")
            if target not in lib:
                raise MaterialError(
                    f"{origin}: bind '{pattern}': unknown material '{target}' "
                    f"(known: {', '.join(lib.names)})"
                )
            bind[pattern] = lib._resolve(target)
        default = data.get("default", None)
        if default is not None:
            if not isinstance(default, str) or default not in lib:
                raise MaterialError(
                    f"{origin}: default: unknown material {brief(default)} (known: {', '.join(lib.names)})"
                )
        else:
            default = self.default
        return MaterialLibrary(mats, bind=bind, default=default)

    # -- mapping --------------------------------------------------------------------------------
    def _key(self, name: str) -> str | None:
        if not isinstance(name, str):
            return None
        key = _canonical(name)
        if key in self._materials:
            return key
        if key.startswith("itu_") and key[4:] in self._materials:
            return key[4:]
        return None

    def _resolve(self, name: str) -> str:
        key = self._key(name)
        if key is None:
            raise MaterialError(f"unknown material {brief(name)} (known: {', '.join(self.names)})")
        return key

    def __getitem__(self, name: str) -> Material:
        return self._materials[self._resolve(name)]

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and self._key(name) is not None

    def get(self, name: str, default: Any = None) -> Any:  # type: ignore[override]
        """Material or ``default`` (``__getitem__`` raises MaterialError, not KeyError)."""
        key = self._key(name)
        return default if key is None else self._materials[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._materials)

    def __len__(self) -> int:
        return len(self._materials)

    def __repr__(self) -> str:
        return (
            f"MaterialLibrary({len(self)} materials, {len(self.bind)} bindings, "
            f"default={brief(self.default)})"
        )

    @property
    def names(self) -> tuple[str, ...]:
        """Material names, sorted."""
        return tuple(sorted(self._materials))

    def match(self, object_name: str) -> str | None:
        """Material whose name appears in an object name, or None.

        Case-insensitive; any run of characters other than letters and digits in the object name
        counts as ``_``, and a material name with ``_`` also matches without it
        (``Ceiling-Board_3``, ``ceilingboard`` -> ``ceiling_board``). An ``itu_`` prefix
        (``mat-itu_glass``) matches as it contains the name. The longest material name found wins
        (``crate_plywood`` -> ``plywood``, not ``wood``); between equally long names the one
        appearing first in the object name wins.

        Parameters
        ----------
        object_name : str

        Returns
        -------
        str or None
            Canonical material name.
        """
        text = re.sub(r"[^a-z0-9]+", "_", str(object_name).lower())
        best: tuple[int, int, str] | None = None  # (-length, position, name)
        for name in self._materials:
            for variant in {name, name.replace("_", "")}:
                pos = text.find(variant)
                if pos >= 0:
                    cand = (-len(name), pos, name)
                    if best is None or cand < best:
                        best = cand
        return None if best is None else best[2]


def _load_yaml(source: str | os.PathLike[str] | Mapping[str, Any]) -> tuple[Mapping, str]:
    if isinstance(source, Mapping):
        return source, "material definition"
    path = Path(source)
    origin = f"material file {path}"
    data = read_yaml(path, "material file", MaterialError)
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise MaterialError(f"{origin}: top level must be a mapping (materials, bind, default)")
    return data, origin


def _material_from_spec(origin: str, name: str, spec: Any, existing: Material | None) -> Material:
    """One ``materials:`` entry of a YAML -> Material (validated, one-line errors)."""
    if not _NAME_RE.match(name):
        raise MaterialError(
            f"{origin}: bad material name {brief(name)}: use letters, digits and '_', starting with a letter"
        )
    if not isinstance(spec, Mapping) or not spec:
        raise MaterialError(
            f"{origin}: material '{name}' needs a mapping of properties "
            "(eta_real and sigma, or a, b, c, d and f_range_ghz; optional thickness)"
        )
    keys = set(spec)
    unknown = sorted(map(str, keys - _MATERIAL_KEYS))
    if unknown:
        raise MaterialError(
            f"{origin}: material '{name}': unknown key(s) {', '.join(unknown)} "
            f"(allowed: {', '.join(sorted(_MATERIAL_KEYS))})"
        )
    thickness = None
    if "thickness" in spec:
        thickness = _number(origin, name, "thickness", spec["thickness"])
        if not (math.isfinite(thickness) and thickness > 0):
            raise MaterialError(f"{origin}: material '{name}': thickness must be > 0 m")
    electrical = keys & _ELECTRICAL_KEYS
    if not electrical:
        if existing is None:
            raise MaterialError(
                f"{origin}: material '{name}' is not known and has no electrical properties "
                "(give eta_real and sigma, or a, b, c, d and f_range_ghz)"
            )
        return replace(existing, thickness_m=thickness, source=origin)

    f_min_hz, f_max_hz = 0.0, math.inf
    if "f_range_ghz" in spec:
        rng = spec["f_range_ghz"]
        if not isinstance(rng, (list, tuple)) or len(rng) != 2:
            raise MaterialError(f"{origin}: material '{name}': f_range_ghz must be [low, high]")
        lo = _number(origin, name, "f_range_ghz", rng[0])
        hi = _number(origin, name, "f_range_ghz", rng[1])
        if not (0 <= lo < hi):
            raise MaterialError(
                f"{origin}: material '{name}': f_range_ghz must satisfy 0 <= low < high, got {rng}"
            )
        f_min_hz, f_max_hz = lo * _GHZ, hi * _GHZ

    power_law = electrical & {"a", "b", "c", "d"}
    if power_law:
        missing = sorted({"a", "b", "c", "d", "f_range_ghz"} - keys)
        if missing:
            raise MaterialError(f"{origin}: material '{name}': missing {', '.join(missing)}")
        if electrical & {"eta_real", "sigma"}:
            raise MaterialError(
                f"{origin}: material '{name}': give either eta_real and sigma or a, b, c, d"
            )
        a, b, c, d = (_number(origin, name, k, spec[k]) for k in ("a", "b", "c", "d"))
        if not (math.isfinite(a) and a > 0):
            raise MaterialError(f"{origin}: material '{name}': a (eta') must be > 0, got {a}")
        if not (math.isfinite(c) and c >= 0):
            raise MaterialError(f"{origin}: material '{name}': c (sigma) must be >= 0, got {c}")
    else:
        missing = sorted({"eta_real", "sigma"} - keys)
        if missing:
            raise MaterialError(f"{origin}: material '{name}': missing {', '.join(missing)}")
        a = _number(origin, name, "eta_real", spec["eta_real"])
        c = _number(origin, name, "sigma", spec["sigma"])
        b = d = 0.0
        if not (math.isfinite(a) and a > 0):
            raise MaterialError(f"{origin}: material '{name}': eta_real must be > 0, got {a}")
        if not (math.isfinite(c) and c >= 0):
            raise MaterialError(f"{origin}: material '{name}': sigma must be >= 0 S/m, got {c}")
    if thickness is None:
        thickness = existing.thickness_m if existing is not None else DEFAULT_USER_THICKNESS_M
    return Material(name, a, b, c, d, f_min_hz, f_max_hz, thickness, source=origin)


def permittivity(
    name: str,
    frequency_hz: float | np.ndarray,
    *,
    extrapolate: bool = False,
    library: MaterialLibrary | None = None,
) -> complex | np.ndarray:
    """Complex relative permittivity of a named material (P.2040-3 eq. 9b and Table 3).

    Parameters
    ----------
    name : str
        Material name (see :class:`MaterialLibrary` for the accepted spellings).
    frequency_hz : float or (...) float array, Hz
    extrapolate : bool
        Outside the material's valid range: ``False`` raises :class:`MaterialError`; ``True``
        warns with :class:`ExtrapolationWarning` and evaluates the power law anyway.
    library : MaterialLibrary, optional
        Defaults to :meth:`MaterialLibrary.itu`.

    Returns
    -------
    eta : complex, or (...) complex128 array
        ``eta' - j sigma / (2 pi f eps0)``.
    """
    lib = MaterialLibrary.itu() if library is None else library
    return lib[name]._permittivity(frequency_hz, extrapolate, stacklevel=4)
