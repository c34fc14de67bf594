"""First-order edge diffraction: Keller points, wedge geometry, UTD coefficients, knife edge.

Physics of one diffraction at a straight wedge edge, vectorised over P candidate
(source, receiver, edge) triples. Visibility is the tracer's business; nothing here casts rays.
One module per part, their public names re-exported here: :mod:`.keller` (Keller's law),
:mod:`.frames` (wedge frames and geometry, validity, the face rule), :mod:`.coefficients`
(transition function, scalar UTD coefficients), :mod:`.operators` (face reflection matrices, the
dyadic coefficient, the diffracted field, the diffractions of the tracer's paths),
:mod:`.knife_edge` (ITU-R P.526); :mod:`.inputs` checks array arguments.

* :func:`keller_points` -- the diffraction point on an edge (Keller's law of edge diffraction).
* :func:`wedge_geometry` -- wedge parameter ``n``, the angles ``phi'`` and ``phi`` of
  Kouyoumjian-Pathak measured from face 0, and the edge-fixed unit vectors.
* :func:`transition_function` -- the UTD transition function ``F(x)``.
* :func:`utd_coefficients` -- soft / hard diffraction coefficients ``D_s``, ``D_h``:
  Kouyoumjian-Pathak (KP) for a perfectly conducting wedge, Luebbers' scalar form with face
  reflection coefficients for a lossy one (normal incidence on the edge).
* :func:`face_reflection_matrix` -- a face's Fresnel reflection as a 2 x 2 matrix in the
  ray-fixed (``beta0``, ``phi``) components, exact at oblique incidence on the edge.
* :func:`diffraction_matrix` -- the dyadic coefficient (UTD with the faces' reflection
  matrices) and the spreading factor, which :func:`diffracted_field` applies to a field.
* :func:`diffracted_field` -- the diffracted field vector at the receiver (KP for perfect
  conductors; for lossy faces Luebbers' heuristic with the face rule below, which makes the field
  independent of how the mesh labels the faces).
* :func:`chain_diffraction` -- the dyadic coefficient and spreading of the diffractions of a
  tracer's unfolded paths, compiled end to end.
* :func:`knife_edge_loss_db`, :func:`fresnel_kirchhoff_v` -- ITU-R P.526 single knife edge.

Conventions (see ``docs/diffraction.md`` for the formulas and their sources)
----------------------------------------------------------------------------
* Time dependence ``exp(+j omega t)``: a wave travelling a distance ``s`` carries
  ``exp(-j k s)``; ``k = 2 pi f / c``.
* Wedge: faces "0" and "n"; the exterior (free space) is ``0 <= phi <= n pi`` with
  ``phi`` measured from face 0 towards face n, right-handed about the oriented edge unit vector
  ``e``. With ``t0`` the unit vector lying in face 0, perpendicular to the edge and pointing from
  the edge into the face, and ``n0`` the outward normal of face 0: ``t0 = n0 x e`` and
  ``n0 = e x t0``; a point ``p`` has ``phi = atan2((p - q).n0, (p - q).t0)`` (``q`` on the edge).
  :func:`wedge_geometry` orients ``e`` itself: the caller only says which face is face 0.
* Lossy faces (Luebbers' heuristic with a reciprocal face rule, D8a): each face's term takes the
  reflection, off the face's plane, of the specular ray between source and receiver seen along
  the edge (each end taken in front of the plane). Reciprocal, continuous in both end points,
  independent of which face is called face 0, the geometrical-optics reflection wherever it is
  seen, and Luebbers' angles in his limits (distant source: the incident ray's ``phi'``; distant
  receiver: the diffracted ray's ``pi - phi``).
* ``n`` = exterior angle / pi: 2 for a half-plane (thin sheet), 1.5 for a right-angle convex
  corner of a box; for a convex wedge ``n = 1 + angle(n0, nn) / pi``.
* Ray-fixed unit vectors (KP): incident direction ``s'`` (source -> edge), ``phi'_hat =
  -(e x s') / |e x s'|``, ``beta0'_hat = s' x phi'_hat``; diffracted direction ``s``
  (edge -> receiver), ``phi_hat = (e x s) / |e x s|``, ``beta0_hat = s x phi_hat``.
  The soft coefficient acts on the ``beta0`` components (the E-field component in the plane of
  the edge and the ray; parallel to the edge at normal incidence), the hard one on the ``phi``
  components.
"""

from __future__ import annotations

from .coefficients import X_SERIES, transition_function, utd_coefficients
from .frames import (
    WedgeFrame,
    WedgeGeometry,
    diffraction_valid,
    diffraction_valid1,
    face_rule_angle,
    framed_wedge_geometry,
    wedge_frames,
    wedge_geometry,
)
from .keller import KELLER_TOL_M, KellerPoints, keller_point, keller_points
from .knife_edge import KNIFE_EDGE_V_MIN, fresnel_kirchhoff_v, knife_edge_loss_db
from .operators import (
    ChainDiffraction,
    DiffractedField,
    chain_diffraction,
    diffracted_field,
    diffraction_matrix,
    face_reflection_matrix,
)

__all__ = [
    "KellerPoints",
    "WedgeGeometry",
    "DiffractedField",
    "keller_points",
    "keller_point",
    "KELLER_TOL_M",
    "wedge_geometry",
    "WedgeFrame",
    "wedge_frames",
    "framed_wedge_geometry",
    "diffraction_valid",
    "diffraction_valid1",
    "face_rule_angle",
    "transition_function",
    "utd_coefficients",
    "face_reflection_matrix",
    "diffraction_matrix",
    "ChainDiffraction",
    "chain_diffraction",
    "diffracted_field",
    "knife_edge_loss_db",
    "fresnel_kirchhoff_v",
    "KNIFE_EDGE_V_MIN",
    "X_SERIES",
]
