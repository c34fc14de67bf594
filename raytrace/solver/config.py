"""The one set of tracer limits: :class:`TraceConfig`.

Every way of setting the limits goes through this dataclass: the library's
``trace(scene, tx, rx, f, TraceConfig(...))``, the command-line flags of the tools
(:func:`add_trace_arguments` / :func:`config_from_args`, generated from the fields) and the keys
of sweep configurations (:data:`TRACE_KEYS`, :meth:`TraceConfig.from_mapping`).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from ..core.errors import TraceInputError

#: Paths whose power gain is below this (dB) carry no power (e.g. through metal) and are dropped.
MIN_POWER_DB = -250.0


def _limit(help_text: str, lo: int, hi: int | None = None) -> dict[str, Any]:
    return {"help": help_text, "kind": "int", "range": (lo, hi)}


@dataclass(frozen=True)
class TraceConfig:
    """Tracer limits and switches (the paper's Table I: each mechanism has its own limit).

    Attributes
    ----------
    max_reflections : int, 0..2, specular reflections on one path
    max_penetrations : int, >= 0, crossings of objects in all along a path
    max_diffractions : int, 0 or 1, edge diffractions on one path
    max_interactions : int, >= 0, reflections plus diffractions on one path (penetrations apart)
    min_power_db : float, dB, paths weaker than this are dropped
    extrapolate : bool, allow materials outside their ITU-R P.2040 frequency range (warns)
    slab_delay : bool, a penetrated slab delays the path by its group delay
        (:func:`raytrace.physics.materials.slab_group_delay`), not only its phase
    facet_reach : float, metres, >= 0; 0 (the default) traces exactly. Above 0, an
        approximation for scenes of many small facets (scanned or tessellated machines): a
        facet whose bounding sphere's radius is below it reflects, in a path of more than one
        reflection or diffraction, only toward or from the interactions next to it on the path
        whose bounding boxes come within this distance of its own
        (:mod:`raytrace.solver.near`); every path found is one the exact tracer finds, with
        the same numbers. Its recall is measured in docs/tracing.md.
    """

    max_reflections: int = field(default=2, metadata=_limit("reflections per path (0-2)", 0, 2))
    max_penetrations: int = field(
        default=2, metadata=_limit("penetrations (object crossings) per path", 0)
    )
    max_diffractions: int = field(default=1, metadata=_limit("diffractions per path (0-1)", 0, 1))
    max_interactions: int = field(
        default=2, metadata=_limit("reflections + diffractions per path", 0)
    )
    min_power_db: float = field(
        default=MIN_POWER_DB,
        metadata={"help": "drop paths weaker than this power gain, dB", "kind": "float"},
    )
    extrapolate: bool = field(
        default=False,
        metadata={"help": "use materials outside their valid frequency range", "kind": "switch"},
    )
    slab_delay: bool = field(
        default=True,
        metadata={
            "help": "penetrating paths are late by each slab's group delay",
            "kind": "switch",
            "off": "--no-slab-delay",
            "off_help": "free-space delays for penetrating paths (default: plus each slab's "
            "group delay)",
        },
    )

    facet_reach: float = field(
        default=0.0,
        metadata={
            "help": "approximate, for scenes of many small facets: a facet of radius below this "
            "(m) pairs, in paths of several interactions, only with edges and facets within "
            "this distance of it (0: exact)",
            "kind": "float",
            "range": (0.0, math.inf),
        },
    )

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            kind = f.metadata["kind"]
            if kind == "int":
                ok = isinstance(value, int) and not isinstance(value, bool)
                lo, hi = f.metadata["range"]
                if not ok or value < lo or (hi is not None and value > hi):
                    span = f"{lo}..{hi}" if hi is not None else f">= {lo}"
                    raise TraceInputError(f"{f.name} must be an integer {span}, got {value!r}")
            elif kind == "float":
                ok = isinstance(value, (int, float)) and not isinstance(value, bool)
                if "range" in f.metadata:  # a finite distance from lo up
                    lo, hi = f.metadata["range"]
                    if not ok or not lo <= value < hi:
                        raise TraceInputError(
                            f"{f.name} must be a finite number >= {lo:g}, got {value!r}")
                elif not ok or math.isnan(value) or value == math.inf:
                    raise TraceInputError(f"{f.name} must be a number or -inf, got {value!r}")
            elif not isinstance(value, bool):
                raise TraceInputError(f"{f.name} must be true or false, got {value!r}")

    def replace(self, **changes: Any) -> TraceConfig:
        """A copy with some fields changed (validated)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> TraceConfig:
        """The config of the keys of ``values`` that are fields (the others are ignored)."""
        return cls(**{k: values[k] for k in TRACE_KEYS if k in values})


#: The field names: the trace keys of sweep configurations.
TRACE_KEYS = tuple(f.name for f in fields(TraceConfig))


def add_trace_arguments(parser: argparse.ArgumentParser, *, skip: tuple[str, ...] = ()) -> None:
    """Add one command-line option per :class:`TraceConfig` field (``--max-reflections``,
    ``--no-slab-delay``, ...), with the dataclass's defaults and help."""
    default = TraceConfig()
    group = parser.add_argument_group("tracer limits")
    for f in fields(TraceConfig):
        if f.name in skip:
            continue
        flag = "--" + f.name.replace("_", "-")
        value = getattr(default, f.name)
        kind = f.metadata["kind"]
        if kind == "int":
            group.add_argument(
                flag, type=int, default=value, help=f"{f.metadata['help']} [{value}]"
            )
        elif kind == "float":
            group.add_argument(
                flag, type=float, default=value, help=f"{f.metadata['help']} [{value:g}]"
            )
        elif value:  # a switch that is on by default: the option turns it off
            group.add_argument(
                f.metadata["off"], dest=f.name, action="store_false", help=f.metadata["off_help"]
            )
        else:
            group.add_argument(flag, action="store_true", help=f.metadata["help"])


def config_from_args(args: argparse.Namespace) -> TraceConfig:
    """The :class:`TraceConfig` of parsed options (fields without an option keep defaults)."""
    return TraceConfig(**{k: getattr(args, k) for k in TRACE_KEYS if hasattr(args, k)})
