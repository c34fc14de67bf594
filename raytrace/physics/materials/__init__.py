"""Building materials (ITU-R P.2040-3 Table 3), Fresnel coefficients and the single-layer slab.

One module per part, their public names re-exported here: :mod:`.table` (the rows of Table 3),
:mod:`.library` (the power-law :class:`Material`, the :class:`MaterialLibrary` with a material
YAML's entries and object binding, :func:`permittivity`), :mod:`.coefficients` (Fresnel, slab,
group delay: compiled scalar helpers and the array functions over them).

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

from .coefficients import (
    clipped_cos1,
    face_reflection,
    fresnel,
    fresnel_reflection,
    group_delay1,
    interface1,
    reflection1,
    slab,
    slab1,
    slab_excess_delay,
    slab_group_delay,
)
from .library import (
    DEFAULT_USER_THICKNESS_M,
    ExtrapolationWarning,
    Material,
    MaterialLibrary,
    permittivity,
)
from .table import ITU_REVISION, ITU_TABLE

__all__ = [
    "DEFAULT_USER_THICKNESS_M",
    "ITU_REVISION",
    "ITU_TABLE",
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
    "clipped_cos1",
    "interface1",
    "slab1",
    "group_delay1",
    "reflection1",
]
