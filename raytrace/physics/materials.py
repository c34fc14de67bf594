"""Building materials (ITU-R P.2040-3 Table 3), Fresnel coefficients and the single-layer slab.

Conventions (see ``docs/materials.md`` for the derivations and the YAML format):

* Time dependence ``exp(+j omega t)``; a plane wave travels as ``exp(-j k . r)``.
* Complex relative permittivity ``eta = eta' - j sigma / (2 pi f eps0)`` (P.2040-3 eq. 9b), so a lossy
  medium has ``Im(eta) < 0``.
* Every complex square root (``sqrt(eta - sin^2 theta)``, ``sqrt(eta)``) takes the branch with
  ``Im <= 0``: the wave ``exp(-j k0 s z)`` then decays into the medium (never grows).
* TE = E perpendicular to the plane of incidence, TM = E parallel to it. The coefficients are ratios of
  field components in the per-wave bases of P.2040-3 section 2.2.1: for every wave (incident,
  reflected, transmitted) ``e_perp`` is the same unit normal to the plane of incidence and
  ``e_par = e_perp x k_hat`` with that wave's own propagation direction ``k_hat``. In that basis
  ``r_tm = (eta cos - s) / (eta cos + s)``: at normal incidence ``r_tm = -r_te``, a perfect conductor
  gives ``r_te = -1`` and ``r_tm = +1``, and at grazing incidence both tend to ``-1``. Any basis with
  ``e_par`` flipped for *all* waves at once gives the same ratios.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from raytrace.core.constants import C0, EPS0

from ..core.errors import MaterialError
from ..core.fileio import read_yaml
from ..core.jit import carray, inline, kernel
from ..core.vec import broadcast_rows

__all__ = [
    "DEFAULT_USER_THICKNESS_M",
    "ITU_REVISION",
    "ExtrapolationWarning",
    "Material",
    "MaterialLibrary",
    "fresnel",
    "face_reflection",
    "fresnel_reflection",
    "permittivity",
    "slab",
    "slab_excess_delay",
    "slab_group_delay",
]

#: Revision of the recommendation whose Table 3 the built-in materials follow.
ITU_REVISION = "ITU-R P.2040-3"
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
                f"bad material name {self.name!r}: use letters, digits and '_', starting with a letter"
            )
        for key in ("a", "b", "c", "d", "f_min_hz", "f_max_hz", "thickness_m"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)):
                raise MaterialError(
                    f"material '{self.name}': {key} must be a number, got {value!r}"
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
                f"{where}, not {_fmt_ghz(bad)} GHz; pass extrapolate=True to extrapolate"
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
        """``f d eta / d f`` of the power-law model, for group delays (:func:`slab_group_delay`).

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


# ITU-R P.2040-3 Table 3 (frequency ranges 1-100 GHz class; the 220-450 GHz rows of glass and ceiling
# board are not included). Thicknesses are typical construction values, chosen here as defaults.
_P2040_SOURCE = f"{ITU_REVISION} Table 3"
_ITU_TABLE: tuple[tuple[str, float, float, float, float, float, float, float], ...] = (
    # name                 a      b     c        d       f_min_hz f_max_hz thickness_m
    ("concrete", 5.24, 0.0, 0.0462, 0.7822, 1e9, 100e9, 0.2),
    ("brick", 3.91, 0.0, 0.0238, 0.16, 1e9, 40e9, 0.1),
    ("plasterboard", 2.73, 0.0, 0.0085, 0.9395, 1e9, 100e9, 0.0125),
    ("wood", 1.99, 0.0, 0.0047, 1.0718, 1e6, 100e9, 0.03),
    ("glass", 6.31, 0.0, 0.0036, 1.3394, 1e8, 100e9, 0.01),
    ("ceiling_board", 1.48, 0.0, 0.0011, 1.075, 1e9, 100e9, 0.015),
    ("chipboard", 2.58, 0.0, 0.0217, 0.78, 1e9, 100e9, 0.02),
    ("plywood", 2.71, 0.0, 0.33, 0.0, 1e9, 40e9, 0.02),
    ("marble", 7.074, 0.0, 0.0055, 0.9262, 1e9, 60e9, 0.03),
    ("floorboard", 3.66, 0.0, 0.0044, 1.3515, 50e9, 100e9, 0.02),
    ("metal", 1.0, 0.0, 1e7, 0.0, 1e9, 100e9, 0.002),
    ("very_dry_ground", 3.0, 0.0, 0.00015, 2.52, 1e9, 10e9, 1.0),
    ("medium_dry_ground", 15.0, -0.1, 0.035, 1.63, 1e9, 10e9, 1.0),
    ("wet_ground", 30.0, -0.4, 0.15, 1.30, 1e9, 10e9, 1.0),
)

_ELECTRICAL_KEYS = frozenset({"eta_real", "sigma", "a", "b", "c", "d", "f_range_ghz"})
_MATERIAL_KEYS = _ELECTRICAL_KEYS | {"thickness"}
_TOP_KEYS = ("materials", "bind", "default")


def _number(origin: str, name: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MaterialError(f"{origin}: material '{name}': {key} must be a number, got {value!r}")
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
                raise MaterialError(f"library entry {key!r} is not a Material")
            if _canonical(key) != mat.name:
                raise MaterialError(f"library key {key!r} differs from material name {mat.name!r}")
            self._materials[mat.name] = mat
        self.bind: dict[str, str] = {str(k): self._resolve(v) for k, v in (bind or {}).items()}
        self.default: str | None = None if default is None else self._resolve(default)

    # -- construction ---------------------------------------------------------------------------
    @classmethod
    def itu(cls) -> MaterialLibrary:
        """The 14 materials of ITU-R P.2040-3 Table 3 with default thicknesses."""
        mats = {
            row[0]: Material(*row, source=_P2040_SOURCE)  # type: ignore[arg-type]
            for row in _ITU_TABLE
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
        for raw_name, spec in entries.items():
            name = _canonical(raw_name)
            if name not in mats and name.startswith("itu_") and name[4:] in mats:
                name = name[4:]
            mats[name] = _material_from_spec(origin, name, spec, mats.get(name))
        bind_in = data.get("bind") or {}
        if not isinstance(bind_in, Mapping):
            raise MaterialError(f"{origin}: 'bind' must be a mapping glob -> material name")
        bind = dict(self.bind)
        lib = MaterialLibrary(mats)
        for pattern, target in bind_in.items():
            if not isinstance(pattern, str) or not pattern:
                raise MaterialError(
                    f"{origin}: bind pattern {pattern!r} must be a non-empty string"
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
                    f"{origin}: default: unknown material {default!r} (known: {', '.join(lib.names)})"
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
            raise MaterialError(f"unknown material {name!r} (known: {', '.join(self.names)})")
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
            f"default={self.default!r})"
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
            f"{origin}: bad material name {name!r}: use letters, digits and '_', starting with a letter"
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


# ---------------------------------------------------------------------------------------------------
# Fresnel and slab coefficients
# ---------------------------------------------------------------------------------------------------
# The coefficients are computed one row at a time by compiled scalar helpers (numba,
# :mod:`raytrace.core.jit`): the tracer's kernels call them for every reflection, wedge face and
# penetration of a path, and the array functions below run them over their broadcast inputs, so
# that there is one implementation of each formula.
@inline
def clipped_cos1(c):
    """``|cos theta|`` clipped to 1, as every coefficient here takes the incidence cosine (the
    angle to the normal *line*; a NaN stays NaN, as with ``np.minimum``): a compiled scalar
    helper for kernels."""
    c = abs(c)
    return 1.0 if c > 1.0 else c


@inline
def _sqrt_decaying(z):
    """Complex square root on the branch ``Im <= 0`` (decaying ``exp(-j k0 s z)``, e^{j w t})."""
    s = np.sqrt(z)
    return -s if s.imag > 0 else s


@inline
def interface1(eta, c):
    """``r_te, r_tm`` of :func:`fresnel` of one row at ``c = |cos theta|`` (clipped to 1), and
    ``s``, ``cos + s``, ``eta cos + s`` (a compiled scalar helper for kernels). Only ``eta = 1``
    at exactly grazing incidence makes a denominator vanish: no interface at all, ``r = 0``."""
    s = _sqrt_decaying(eta - (1.0 - c * c))
    d_te = c + s
    d_tm = eta * c + s
    r_te = (c - s) / d_te if d_te != 0 else 0j
    r_tm = (eta * c - s) / d_tm if d_tm != 0 else 0j
    return r_te, r_tm, s, d_te, d_tm


@inline
def _expm1(z):
    """``exp(z) - 1`` of a complex ``z``, accurate for small ``|z|`` (numpy's formula)."""
    a = np.sin(0.5 * z.imag)
    return complex(np.expm1(z.real) * np.cos(z.imag) - 2.0 * a * a, np.exp(z.real) * np.sin(z.imag))


@inline
def _slab_pair(n, k, s, u, phase):
    """``R, T`` of :func:`slab` from ``N``, ``K`` of one polarisation (its docstring)."""
    den = k + n * n * u
    if den == 0:  # only without an interface (eta = 1 at grazing incidence)
        return 0j, phase
    inv = 1.0 / den
    # N (N + 2 s) = N D: D = cos + s = N + 2 s (TE), D = eta cos + s = N + 2 s (TM)
    return n * (n + 2.0 * s) * u * inv, k * phase * inv


@inline
def slab1(eta, c, d, f, p2040):
    """``R_te, R_tm, T_te, T_tm`` of :func:`slab` of one row at ``c = |cos theta|`` (clipped to
    1), thickness ``d`` (m), frequency ``f`` (Hz), ``T``'s phase reference P.2040's where
    ``p2040`` (a compiled scalar helper for kernels)."""
    if d == 0.0:
        return 0j, 0j, 1.0 + 0j, 1.0 + 0j
    s = _sqrt_decaying(eta - (1.0 - c * c))
    k0d = 2.0 * np.pi * f * d / C0
    q = k0d * s
    u = -_expm1(-2j * q)  # 1 - e^{-j2q}, accurate for a thin slab
    if p2040:
        phase = np.exp(-1j * q)
    else:
        # e^{-jq} e^{+j k0 d cos}: Im(s - cos) = Im(s) <= 0, so this never grows
        phase = np.exp(-1j * k0d * (s - c))
    r_te, t_te = _slab_pair(c - s, 4.0 * c * s, s, u, phase)
    r_tm, t_tm = _slab_pair(eta * c - s, 4.0 * eta * c * s, s, u, phase)
    return r_te, r_tm, t_te, t_tm


@inline
def group_delay1(eta, c, d, slope):
    """:func:`slab_group_delay` of one row at ``c = |cos theta|`` (clipped to 1), seconds (a
    compiled scalar helper for kernels)."""
    s = np.sqrt(eta - (1.0 - c * c))  # principal branch: Re(s) >= 0, Im(s) <= 0 for Im(eta) <= 0
    sl = slope / (2.0 * s) if s != 0 else 0j
    return d * ((s + sl).real - c) / C0


@inline
def reflection1(eta, c, two_sided, d, f):
    """``r_te, r_tm`` of a face at ``c = |cos theta|`` (clipped to 1): a closed solid's face is
    a half-space interface (:func:`interface1`), an open sheet (``two_sided``) a slab of
    thickness ``d`` (:func:`slab1`)."""
    if two_sided:
        r_te, r_tm, _, _ = slab1(eta, c, d, f, False)
        return r_te, r_tm
    r_te, r_tm, _, _, _ = interface1(eta, c)
    return r_te, r_tm


_C16 = "c16[::1]"


@kernel(f"Tuple(({_C16}, {_C16}, {_C16}, {_C16}))(c16[::1], f8[::1], b1)")
def _fresnel_rows(eta, cos, transmission):
    """:func:`fresnel` over n rows (``t_te``, ``t_tm`` left zero unless ``transmission``)."""
    n = len(cos)
    r_te, r_tm = np.empty(n, np.complex128), np.empty(n, np.complex128)
    t_te, t_tm = np.zeros(n, np.complex128), np.zeros(n, np.complex128)
    for i in range(n):
        e, c = eta[i], clipped_cos1(cos[i])
        r_te[i], r_tm[i], _, d_te, d_tm = interface1(e, c)
        if transmission:
            t_te[i] = 2.0 * c / d_te if d_te != 0 else 1.0 + 0j
            t_tm[i] = 2.0 * _sqrt_decaying(e) * c / d_tm if d_tm != 0 else 1.0 + 0j
    return r_te, r_tm, t_te, t_tm


@kernel(f"Tuple(({_C16}, {_C16}, {_C16}, {_C16}))(c16[::1], f8[::1], f8[::1], f8[::1], b1)")
def _slab_rows(eta, cos, d, f, p2040):
    """:func:`slab` over n rows."""
    n = len(cos)
    r_te, r_tm = np.empty(n, np.complex128), np.empty(n, np.complex128)
    t_te, t_tm = np.empty(n, np.complex128), np.empty(n, np.complex128)
    for i in range(n):
        r_te[i], r_tm[i], t_te[i], t_tm[i] = slab1(eta[i], clipped_cos1(cos[i]), d[i], f[i],
                                                   p2040)  # fmt: skip
    return r_te, r_tm, t_te, t_tm


@kernel("f8[::1](c16[::1], f8[::1], f8[::1], c16[::1])")
def _group_delay_rows(eta, cos, d, slope):
    """:func:`slab_group_delay` over n rows."""
    out = np.empty(len(cos))
    for i in range(len(cos)):
        out[i] = group_delay1(eta[i], clipped_cos1(cos[i]), d[i], slope[i])
    return out


@kernel(f"Tuple(({_C16}, {_C16}))(c16[::1], f8[::1], i8[::1], f8[::1], b1[::1], f8)")
def _face_rows(eta, thickness, mat, cos, two_sided, f):
    """:func:`face_reflection` over n rows."""
    n = len(cos)
    r_te, r_tm = np.empty(n, np.complex128), np.empty(n, np.complex128)
    for i in range(n):
        m = mat[i]
        r_te[i], r_tm[i] = reflection1(eta[m], clipped_cos1(cos[i]), two_sided[i], thickness[m],
                                       f)  # fmt: skip
    return r_te, r_tm


def _out(x: np.ndarray) -> Any:
    """0-d arrays to numpy scalars, arrays unchanged."""
    return x[()] if x.ndim == 0 else x


def fresnel(eta: complex | np.ndarray, cos_theta: float | np.ndarray) -> tuple[Any, Any, Any, Any]:
    """Fresnel coefficients of a single air -> medium interface (P.2040-3 section 2.2.1).

    ``s = sqrt(eta - sin^2 theta)`` (branch ``Im(s) <= 0``);
    ``r_te = (cos - s) / (cos + s)``, ``r_tm = (eta cos - s) / (eta cos + s)``,
    ``t_te = 2 cos / (cos + s)``, ``t_tm = 2 sqrt(eta) cos / (eta cos + s)``: the interface
    coefficients of P.2040-3 section 2.2.1.1 with air as the incident medium (section 2.2.1.5).

    The coefficients are ratios of complex electric-field components in the TE (perpendicular) /
    TM (parallel) bases of P.2040-3 section 2.2.1: ``e_perp`` normal to the plane of incidence,
    common to all waves; ``e_par = e_perp x k_hat`` for each wave with its own direction. Hence
    ``r_tm(normal) = -r_te(normal) = (sqrt(eta) - 1) / (sqrt(eta) + 1)``; a perfect conductor has
    ``r_te = -1``, ``r_tm = +1``. For a reflection in a 3D tracer, build ``e_perp`` from
    ``k_i x n`` and ``e_par`` as above for the incident and the reflected direction and scale the two
    components by ``r_te`` and ``r_tm``.

    Parameters
    ----------
    eta : complex or (...) complex array
        Relative permittivity of the medium (``Im(eta) <= 0`` for a lossy one).
    cos_theta : float or (...) float array
        Cosine of the incidence angle to the surface normal; the sign is ignored (``|cos|``), values
        are clipped to 1. Broadcasts with ``eta``.

    Returns
    -------
    r_te, r_tm, t_te, t_tm : complex128 (broadcast shape of the inputs)
    """
    shape, (e, c) = broadcast_rows(np.asarray(eta, dtype=complex), np.asarray(cos_theta, dtype=float))
    return tuple(_out(x.reshape(shape)) for x in _fresnel_rows(e, c, True))


def fresnel_reflection(eta: complex | np.ndarray, cos_theta: float | np.ndarray) -> tuple[Any, Any]:
    """``r_te, r_tm`` of :func:`fresnel` alone (the same arithmetic, without the transmission
    coefficients and their square root): what a reflection needs."""
    shape, (e, c) = broadcast_rows(np.asarray(eta, dtype=complex), np.asarray(cos_theta, dtype=float))
    r_te, r_tm, _, _ = _fresnel_rows(e, c, False)
    return _out(r_te.reshape(shape)), _out(r_tm.reshape(shape))


def face_reflection(
    eta: np.ndarray,
    thickness_m: np.ndarray,
    material: np.ndarray,
    cos_theta: np.ndarray,
    two_sided: np.ndarray,
    frequency_hz: float,
) -> tuple[np.ndarray, np.ndarray]:
    """TE/TM reflection coefficients of faces: a closed solid's face is a half-space interface
    (:func:`fresnel`), an open sheet a slab of its material's thickness (:func:`slab`,
    ITU-R P.2040-3 section 2.2.2.2).

    Parameters
    ----------
    eta : (n_materials,) complex, relative permittivity of each material
    thickness_m : (n_materials,) float, m, slab thickness of each material
    material : (n,) int, the material of each face
    cos_theta : (n,) float, cosine of the incidence angle (sign ignored, clipped to 1)
    two_sided : (n,) bool, the face is an open sheet's
    frequency_hz : float, Hz

    Returns
    -------
    r_te, r_tm : (n,) complex128

    Raises
    ------
    MaterialError
        Tables of different lengths, a material index outside them, per-face arrays of
        different lengths.
    """
    eta, thickness = carray(eta, complex).reshape(-1), carray(thickness_m).reshape(-1)
    material = carray(material, np.int64).reshape(-1)
    cos, sheet = carray(cos_theta).reshape(-1), carray(two_sided, bool).reshape(-1)
    if len(eta) != len(thickness):
        raise MaterialError(f"{len(eta)} permittivities but {len(thickness)} thicknesses")
    if not len(material) == len(cos) == len(sheet):
        raise MaterialError("material, cos_theta and two_sided need one value per face")
    if len(material) and (material.min() < 0 or material.max() >= len(eta)):
        raise MaterialError(f"material indices must be in 0..{len(eta) - 1}")
    return _face_rows(eta, thickness, material, cos, sheet, float(frequency_hz))


def slab(
    eta: complex | np.ndarray,
    cos_theta: float | np.ndarray,
    thickness_m: float | np.ndarray,
    frequency_hz: float | np.ndarray,
    *,
    reference: Literal["free_space", "p2040"] = "free_space",
) -> tuple[Any, Any, Any, Any]:
    """Reflection and transmission of a homogeneous slab in air (P.2040-3 section 2.2.2.2).

    With ``R'`` the interface coefficient of :func:`fresnel` (TE or TM), ``s = sqrt(eta - sin^2)``
    and ``q = (2 pi d / lambda) s``:

        ``R = R' (1 - e^{-j2q}) / (1 - R'^2 e^{-j2q})``,
        ``T = (1 - R'^2) e^{-jq} / (1 - R'^2 e^{-j2q})``.

    They are evaluated in a form that never divides by ``cos + s`` and never forms ``1 - R'^2`` by
    cancellation: with ``N = cos - s`` (TE) or ``eta cos - s`` (TM), ``K = 4 cos s`` (TE) or
    ``4 eta cos s`` (TM), ``u = 1 - e^{-j2q}`` (``expm1``),
    ``R = N (N + 2 s) u / (K + N^2 u)``, ``T = K e^{-jq} / (K + N^2 u)``. Because ``Im(q) <= 0``,
    ``|e^{-jq}| <= 1``: a thick lossy (or metal) slab gives ``T -> 0`` and ``R -> R'`` without
    overflow or NaN. ``thickness_m == 0`` gives exactly ``R = 0``, ``T = 1``.

    Phase reference of ``T``
        ``reference="p2040"`` returns ``T`` as printed in P.2040: the transmitted field at the exit face
        relative to the incident field at the entry face, at the same position along the surface
        (the two points a normal apart). ``reference="free_space"`` (default) returns
        ``T * exp(+j k0 d cos theta)``: the transmitted field relative to the field that would be at
        the same point without the slab. That is the factor a tracer multiplies into the free-space
        term computed over the full unfolded straight path (air slab: ``T == 1``). The two differ
        only in phase. ``R`` is referenced to the front face in both cases (image method).

    Parameters
    ----------
    eta : complex or (...) complex array
        Relative permittivity of the slab.
    cos_theta : float or (...) float array
        Cosine of the incidence angle (sign ignored, clipped to 1).
    thickness_m : float or (...) float array, m
        Slab thickness ``d >= 0``.
    frequency_hz : float or (...) float array, Hz
    reference : {"free_space", "p2040"}
        Phase reference of ``T`` (see above).

    Returns
    -------
    R_te, R_tm, T_te, T_tm : complex128, broadcast shape of the inputs
        Field ratios in the bases of :func:`fresnel` (air on both sides, so ``|R|^2 + |T|^2`` is
        the power balance: 1 for a lossless slab, < 1 for a lossy one).

    Raises
    ------
    MaterialError
        Negative or non-finite thickness, non-positive frequency, unknown ``reference``.
    """
    if reference not in ("free_space", "p2040"):
        raise MaterialError(f"slab reference must be 'free_space' or 'p2040', got {reference!r}")
    d = np.asarray(thickness_m, dtype=float)
    f = np.asarray(frequency_hz, dtype=float)
    if np.any(~np.isfinite(d) | (d < 0)):
        raise MaterialError("slab thickness must be finite and >= 0 m")
    if np.any(~np.isfinite(f) | (f <= 0)):
        raise MaterialError("slab frequency must be finite and > 0 Hz")
    shape, (e, c, dd, ff) = broadcast_rows(np.asarray(eta, dtype=complex),
                                           np.asarray(cos_theta, dtype=float), d, f)  # fmt: skip
    out = _slab_rows(e, c, dd, ff, reference == "p2040")
    return tuple(_out(x.reshape(shape)) for x in out)


def slab_group_delay(
    eta: complex | np.ndarray,
    cos_theta: float | np.ndarray,
    thickness_m: float | np.ndarray,
    eta_slope: complex | np.ndarray = 0.0,
) -> Any:
    """Group delay of the ray straight through a slab, relative to free space over the same line.

    The through-ray carries ``exp(-j k0 d (s - cos theta))`` with ``s = sqrt(eta - sin^2 theta)``
    (the phase of :func:`slab`'s ``T`` with ``reference="free_space"``, without the interface
    factors); its group delay ``-d phase / d omega`` is

        ``tau = (d / c) [Re(s + f (d eta / d f) / (2 s)) - cos theta]``,

    since ``d(omega s)/d omega = s + omega (d s / d omega)`` and ``d s / d eta = 1 / (2 s)``. With
    ``eta`` real and constant it is the optical path excess ``d (n cos theta_t - cos theta) / c`` of
    geometric optics. Multiple internal reflections (Fabry-Perot ripple, damped out in any lossy
    wall) are neglected.

    Parameters
    ----------
    eta : complex or (...) complex array, relative permittivity of the slab
    cos_theta : float or (...) float array, cosine of the incidence angle (sign ignored, <= 1)
    thickness_m : float or (...) float array, m
    eta_slope : complex or (...) complex array
        ``f d eta / d f`` at the carrier (:meth:`Material.permittivity_slope`); 0 for a
        frequency-independent permittivity.

    Returns
    -------
    tau : float or (...) float64, seconds (>= 0 for the building materials of P.2040)
    """
    shape, (e, c, d, s) = broadcast_rows(
        np.asarray(eta, dtype=complex), np.asarray(cos_theta, dtype=float),
        np.asarray(thickness_m, dtype=float), np.asarray(eta_slope, dtype=complex),
    )
    return _out(_group_delay_rows(e, c, d, s).reshape(shape))


def slab_excess_delay(
    eta: complex | np.ndarray, cos_theta: float | np.ndarray, thickness_m: float | np.ndarray
) -> Any:
    """Extra delay of the ray straight through a slab, relative to free space over the same line.

    ``tau = d (Re sqrt(eta' - sin^2 theta) - cos theta) / c`` (optical path ``d (n cos theta_t -
    cos theta)`` of geometric optics). It is the group delay of the through-ray when ``eta'`` does not
    depend on frequency (all P.2040-3 building materials except the grounds have ``b = 0``) and
    the slab is lossless; :func:`slab_group_delay` is the general form (loss and dispersion), of
    which this is the limit for ``Im(eta) = 0``.

    Parameters
    ----------
    eta : complex or (...) complex array
        Slab permittivity (only ``Re(eta)`` is used).
    cos_theta : float or (...) float array
        Cosine of the incidence angle (sign ignored, clipped to 1).
    thickness_m : float or (...) float array, m

    Returns
    -------
    tau : float or (...) float64, seconds (>= 0 for ``eta' >= 1``)
    """
    return slab_group_delay(np.real(np.asarray(eta, dtype=complex)), cos_theta, thickness_m)
