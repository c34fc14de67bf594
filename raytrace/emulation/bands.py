"""Radio bands: carrier, bandwidth and OFDM numerology (paper Table I), and user bands from YAML.

The two built-in bands are the paper's Table I settings:

========  ============  ==========  ===================
name      carrier       bandwidth   subcarrier spacing
========  ============  ==========  ===================
c-band    3.775 GHz     100 MHz     30 kHz  (NR mu = 1)
mmwave    26.85 GHz     400 MHz     120 kHz (NR mu = 3)
========  ============  ==========  ===================

User bands come from YAML (units in the key names; converted to SI here, at the edge)::

    bands:
      wifi6e: {frequency_ghz: 6.1, bandwidth_mhz: 160, subcarrier_khz: 78.125}
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hallray.errors import brief

from ..core.constants import wavelength
from ..core.errors import HallrayError
from ..core.fileio import read_yaml

__all__ = [
    "BUILTIN_BANDS",
    "Band",
    "band_from_dict",
    "get_band",
    "load_bands",
]

_YAML_KEYS = ("frequency_ghz", "bandwidth_mhz", "subcarrier_khz")


@dataclass(frozen=True)
class Band:
    """One radio band: carrier, channel bandwidth and OFDM subcarrier spacing (SI units).

    Parameters
    ----------
    name : str
        Lower-case identifier (``"c-band"``, ``"mmwave"`` or a user name).
    center_frequency_hz : float, Hz
        Carrier frequency; the tracer evaluates materials and path gains here.
    bandwidth_hz : float, Hz
        Channel (signal) bandwidth B: the ``B`` of the paper's eq. 3 and the band the pulse of
        eq. 2 is confined to, see :mod:`raytrace.emulation.channel`.
    subcarrier_spacing_hz : float, Hz
        OFDM subcarrier spacing (NR numerology: 15 * 2**mu kHz).
    """

    name: str
    center_frequency_hz: float
    bandwidth_hz: float
    subcarrier_spacing_hz: float

    def __post_init__(self) -> None:
        for field in ("center_frequency_hz", "bandwidth_hz", "subcarrier_spacing_hz"):
            value = getattr(self, field)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise HallrayError(
                    f"band {brief(self.name)}: {field} must be a positive number, got {brief(value)}"
                )
            object.__setattr__(self, field, float(value))
        if self.subcarrier_spacing_hz > self.bandwidth_hz:
            raise HallrayError(
                f"band {brief(self.name)}: subcarrier spacing {self.subcarrier_spacing_hz:g} Hz exceeds "
                f"the bandwidth {self.bandwidth_hz:g} Hz"
            )
        if self.bandwidth_hz >= 2 * self.center_frequency_hz:
            raise HallrayError(f"band {brief(self.name)}: bandwidth must be below twice the carrier")

    @property
    def n_subcarriers(self) -> int:
        """Number of subcarriers that fit the bandwidth, floor(B / spacing) (3333 for both bands).

        NR leaves a guard band: 100 MHz at 30 kHz carries 273 resource blocks = 3276 subcarriers,
        400 MHz at 120 kHz 264 RBs = 3168 (TS 38.101-1/-2). The difference in processing gain is
        0.1-0.2 dB, below anything this emulation resolves.
        """
        return int(math.floor(self.bandwidth_hz / self.subcarrier_spacing_hz + 1e-9))

    @property
    def symbol_duration_s(self) -> float:
        """Useful OFDM symbol duration 1 / spacing, s (without cyclic prefix)."""
        return 1.0 / self.subcarrier_spacing_hz

    @property
    def sample_period_s(self) -> float:
        """Nyquist sample period 1 / B, s (complex baseband)."""
        return 1.0 / self.bandwidth_hz

    @property
    def wavelength_m(self) -> float:
        """Free-space wavelength at the carrier, m."""
        return float(wavelength(self.center_frequency_hz))

    def describe(self) -> str:
        """One-line human-readable summary (for logs and CLI output)."""
        return (
            f"{self.name}: {self.center_frequency_hz / 1e9:g} GHz, "
            f"{self.bandwidth_hz / 1e6:g} MHz, "
            f"{self.subcarrier_spacing_hz / 1e3:g} kHz subcarriers ({self.n_subcarriers})"
        )


#: The paper's Table I bands, keyed by name.
BUILTIN_BANDS: Mapping[str, Band] = {
    "c-band": Band("c-band", 3.775e9, 100e6, 30e3),
    "mmwave": Band("mmwave", 26.85e9, 400e6, 120e3),
}


def _normalise(name: str) -> str:
    return str(name).strip().lower().replace("_", "-").replace(" ", "-")


def band_from_dict(name: str, entry: Mapping[str, Any]) -> Band:
    """Band from one YAML entry ``{frequency_ghz, bandwidth_mhz, subcarrier_khz}``.

    Raises
    ------
    HallrayError
        Missing, unknown or non-numeric keys (one-line message naming the band and the key).
    """
    if not isinstance(entry, Mapping):
        raise HallrayError(f"band {brief(name)}: expected a mapping with keys {', '.join(_YAML_KEYS)}")
    unknown = sorted(set(map(str, entry)) - set(_YAML_KEYS))
    if unknown:
        raise HallrayError(
            f"band {brief(name)}: unknown key(s) {', '.join(unknown)}; expected {', '.join(_YAML_KEYS)}"
        )
    missing = [k for k in _YAML_KEYS if k not in entry]
    if missing:
        raise HallrayError(f"band {brief(name)}: missing key(s) {', '.join(missing)}")
    values = {}
    for key in _YAML_KEYS:
        value = entry[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise HallrayError(f"band {brief(name)}: {key} must be a number, got {brief(value)}")
        values[key] = float(value)
    return Band(
        _normalise(name),
        values["frequency_ghz"] * 1e9,
        values["bandwidth_mhz"] * 1e6,
        values["subcarrier_khz"] * 1e3,
    )


def _read_yaml(path: Path) -> Any:
    return read_yaml(path, "band file")


def _user_bands(source: str | os.PathLike[str] | Mapping[str, Any]) -> dict[str, Band]:
    data = source if isinstance(source, Mapping) else _read_yaml(Path(source))
    where = "band definition" if isinstance(source, Mapping) else f"band file {source}"
    if not isinstance(data, Mapping) or not isinstance(data.get("bands"), Mapping):
        raise HallrayError(f"{where}: expected a top-level 'bands:' mapping of name -> settings")
    if not data["bands"]:
        raise HallrayError(f"{where}: 'bands:' is empty")
    return {_normalise(n): band_from_dict(n, e) for n, e in data["bands"].items()}


def load_bands(source: str | os.PathLike[str] | Mapping[str, Any] | None = None) -> dict[str, Band]:
    """Built-in bands plus the user bands of a YAML file or an already parsed mapping.

    A user band with a built-in name replaces the built-in one.

    Parameters
    ----------
    source : path or mapping, optional
        YAML file (or dict) with a top-level ``bands:`` mapping; None gives the built-ins only.

    Returns
    -------
    dict[str, Band]
        Name -> band.
    """
    bands = dict(BUILTIN_BANDS)
    if source is not None:
        bands.update(_user_bands(source))
    return bands


def _looks_like_path(text: str) -> bool:
    return text.lower().endswith((".yaml", ".yml")) or os.sep in text or "/" in text


def get_band(
    name_or_path: str | os.PathLike[str] | Band, bands: Mapping[str, Band] | None = None
) -> Band:
    """Band by name (``"c-band"``, ``"mmwave"``, a user band) or from a YAML file with one band.

    Parameters
    ----------
    name_or_path : str, path or Band
        A name (case-insensitive; ``_`` and ``-`` are equivalent), a YAML file defining exactly
        one band, or a :class:`Band` (returned as is).
    bands : mapping, optional
        Name -> band to look names up in, e.g. ``load_bands("my_bands.yaml")``; default the
        built-in bands.

    Raises
    ------
    HallrayError
        Unknown name (the message lists the known ones), unreadable file, or a file defining
        several bands (the message lists them; pick one with ``bands=load_bands(path)``).
    """
    if isinstance(name_or_path, Band):
        return name_or_path
    known = dict(BUILTIN_BANDS) if bands is None else dict(bands)
    text = os.fspath(name_or_path)
    key = _normalise(text)
    if key in known:
        return known[key]
    if _looks_like_path(text) or Path(text).is_file():
        user = _user_bands(text)
        if len(user) != 1:
            raise HallrayError(
                f"band file {text} defines {len(user)} bands ({', '.join(user)}); choose one by "
                "name with bands=load_bands(path)"
            )
        return next(iter(user.values()))
    raise HallrayError(f"unknown band {brief(text)}; known bands: {', '.join(known)}")
