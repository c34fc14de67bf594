"""The drawing colours of radio materials: one palette for the hall GLBs (glTF base colours), the
top view, the rendered pictures and the reconstructed scans.

A material named in :data:`MATERIAL_COLORS` always has that colour. Other materials (user
materials, the ITU ground types) take the :data:`FALLBACK_COLORS` in turn, in the sorted order
of the materials of the picture or scene that have no named colour, so that two of them in one
picture differ (up to four). :func:`material_colors` applies the rule to a set of materials.
"""

from __future__ import annotations

from collections.abc import Iterable

RGB = tuple[float, float, float]

#: Named colours (RGB in 0..1): the ITU-R P.2040 materials of a hall and the reference hall's
#: ``plastic``.
MATERIAL_COLORS: dict[str, RGB] = {
    "concrete": (0.62, 0.62, 0.60),
    "brick": (0.70, 0.35, 0.25),
    "plasterboard": (0.88, 0.85, 0.76),
    "wood": (0.64, 0.45, 0.25),
    "glass": (0.55, 0.82, 0.92),
    "ceiling_board": (0.92, 0.92, 0.88),
    "chipboard": (0.80, 0.66, 0.45),
    "plywood": (0.76, 0.60, 0.38),
    "marble": (0.90, 0.90, 0.92),
    "floorboard": (0.58, 0.40, 0.24),
    "metal": (0.33, 0.44, 0.62),
    "plastic": (0.95, 0.62, 0.18),
}
#: Colours of the materials without a named one, taken in turn.
FALLBACK_COLORS: tuple[RGB, ...] = (
    (0.55, 0.35, 0.65),
    (0.30, 0.60, 0.35),
    (0.80, 0.30, 0.50),
    (0.40, 0.40, 0.40),
)


def material_colors(materials: Iterable[str]) -> dict[str, RGB]:
    """The colour of each of a set of materials (the materials of one scene or picture).

    Parameters
    ----------
    materials : material names (duplicates and order do not matter)

    Returns
    -------
    dict, material -> (r, g, b) in 0..1: the named colour, else the fallback colours in turn
    over the sorted materials without a named colour
    """
    names = set(materials)
    unnamed = sorted(names - set(MATERIAL_COLORS))
    out = {m: MATERIAL_COLORS[m] for m in sorted(names) if m in MATERIAL_COLORS}
    for k, m in enumerate(unnamed):
        out[m] = FALLBACK_COLORS[k % len(FALLBACK_COLORS)]
    return out
