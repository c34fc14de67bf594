"""Hall description (YAML) -> validated :class:`HallSpec` -> trimesh scene -> GLB.

A hall is written as a short YAML file (schema in ``docs/hall.md``): the interior size, user
materials, a list of primitives (boxes, vertical cylinders, open rectangular sheets), reusable
templates placed many times (rows of racks), base stations, points of interest, forklift routes and
an area of interest. :func:`load_hall_spec` validates it strictly (every error is one line naming the
bad entry); :func:`build_scene` turns it into a :class:`trimesh.Scene` with one node per object whose
name carries its material (``rack_a03_frame_itu_metal``, ``rack_a03_boxes_plastic``), which is what
the scene loader binds materials by; :func:`write_glb` writes it reproducibly (same YAML -> same bytes)
and atomically.

Geometry conventions (SI, metres): x east, y north, z up; the hall interior is exactly
``[0, X] x [0, Y] x [0, Z]``; the floor, ceiling and four walls are closed slabs *outside* it. Closed
solids are watertight with outward normals; sheets are two triangles, open and two-sided.

Modules: :mod:`.model` (primitives, sites, :class:`HallSpec`), :mod:`.parse` (YAML ->
:class:`HallSpec`), :mod:`.build` (trimesh scene, GLB, metadata), :mod:`.los` (the tracer's
scene and the line-of-sight table). The top view of a hall is
:func:`raytrace.viz.topview.plot_top_view`.
"""

from ...scene.motion import Route
from .build import (
    build_scene,
    glb_bytes,
    hall_metadata,
    object_mesh,
    paint,
    scene_from_primitives,
    write_glb,
)
from .los import (
    line_of_sight,
    los_markdown,
    los_note,
    object_name,
    parse_los_note,
    segment_blockers,
    tracer_scene,
)
from .model import (
    BOUNDS_TOL_M,
    DEFAULT_CYLINDER_SECTIONS,
    DRIVE_OVER_HEIGHT_M,
    ITU_MATERIALS,
    POINT_CLEARANCE_M,
    SCHEMA_VERSION,
    BaseStation,
    Box,
    Cylinder,
    HallSpec,
    PointOfInterest,
    Primitive,
    Sheet,
    footprint_xy,
    node_name,
    primitive_arrays,
    primitive_bounds,
    rotate_xy,
)
from .parse import load_hall_spec, parse_hall_spec

__all__ = [
    "BOUNDS_TOL_M",
    "DEFAULT_CYLINDER_SECTIONS",
    "DRIVE_OVER_HEIGHT_M",
    "ITU_MATERIALS",
    "POINT_CLEARANCE_M",
    "SCHEMA_VERSION",
    "BaseStation",
    "Box",
    "Cylinder",
    "HallSpec",
    "PointOfInterest",
    "Primitive",
    "Route",
    "Sheet",
    "build_scene",
    "footprint_xy",
    "glb_bytes",
    "hall_metadata",
    "line_of_sight",
    "load_hall_spec",
    "los_markdown",
    "los_note",
    "node_name",
    "object_mesh",
    "object_name",
    "paint",
    "parse_hall_spec",
    "parse_los_note",
    "primitive_arrays",
    "primitive_bounds",
    "rotate_xy",
    "scene_from_primitives",
    "segment_blockers",
    "tracer_scene",
    "write_glb",
]
