"""ITU-R P.2040-3 Table 3: the built-in materials' power-law parameters and default thicknesses
(rows of :data:`ITU_TABLE`, which :meth:`raytrace.physics.materials.MaterialLibrary.itu` turns
into :class:`~raytrace.physics.materials.Material` entries)."""

from __future__ import annotations

__all__ = ["ITU_REVISION", "P2040_SOURCE", "ITU_TABLE"]


#: Revision of the recommendation whose Table 3 the built-in materials follow.
ITU_REVISION = "ITU-R P.2040-3"

#: The ``source`` of the built-in materials, for messages.
P2040_SOURCE = f"{ITU_REVISION} Table 3"

#: ITU-R P.2040-3 Table 3 (frequency ranges 1-100 GHz class; the 220-450 GHz rows of glass and
#: ceiling board are not included). Thicknesses are typical construction values, chosen here as
#: defaults.
ITU_TABLE: tuple[tuple[str, float, float, float, float, float, float, float], ...] = (
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
