"""The canonical wedges of the comparison, built from code, and their export as PLY + Mitsuba /
Sionna RT scene XML (both tools load the same file)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from raytrace.core.fileio import write_atomic

#: Receivers on either side of a boundary, at these multiples of --delta-rad from it: the total
#: field is extrapolated to the boundary from each side (quadratic through three samples), so a
#: smooth field gives no step whatever the interference pattern's slope.
BOUNDARY_STEPS = (1, 2, 3)


@dataclass
class Sweep:
    """One transmitter and an arc of receivers around the studied edge (local polar coordinates:
    ``rho`` from the edge, ``phi`` from face 0 towards face n, ``z`` along the edge)."""

    name: str
    tx_local: tuple[float, float, float]  # (rho', phi', z')
    rx_rho: float
    rx_z: float
    phi: np.ndarray  # (R,) receiver azimuths, rad
    boundaries: dict[str, float]  # label -> phi of the boundary, rad
    lit: str  # "face 0", "both faces": which faces the source lights
    oblique: bool
    delta: float  # rad, sample spacing beside the boundaries


@dataclass
class Canon:
    """A canonical scene: meshes, their materials and the studied edge.

    The local frame has the edge on its z axis, face 0 along +x (plane y = 0), the air at
    ``0 < phi < n pi``; ``rotation`` maps local to world coordinates.
    """

    name: str
    title: str
    material: str  # ITU-R P.2040 name
    thickness_m: float  # slab thickness written to the XML (Sionna: every face; hallray: sheets)
    solid: bool  # closed solid (hallray: half-space Fresnel) or open sheet (slab)
    n: float  # exterior angle / pi
    size_m: float
    #: exact solution (wedge_exact) applies: "soft" (vertical edge, perfect conductor, any
    #: obliquity), "hard" (horizontal edge: in the plane normal to the edge only), None
    truth: str | None = None
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    sweeps: list[Sweep] = field(default_factory=list)

    # -- geometry -------------------------------------------------------------------------------
    def to_world(self, p_local: np.ndarray) -> np.ndarray:
        return np.asarray(p_local, float) @ self.rotation.T

    def from_world(self, p: np.ndarray) -> np.ndarray:
        return np.asarray(p, float) @ self.rotation

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """Vertices (world) and triangles: a box filling the wedge's interior angle (n = 1.5), or
        a square sheet on face 0 (n = 2); shared vertices, so Mitsuba finds the edge's faces."""
        a = self.size_m
        if self.solid:
            # the interior x > 0, y < 0 (phi in (3 pi / 2, 2 pi))
            lo, hi = np.array([0.0, -a, -a]), np.array([a, 0.0, a])
            v = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                          for i in (0, 1) for j in (0, 1) for k in (0, 1)])
            f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                          [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
        else:
            v = np.array([[0.0, 0.0, -a], [a, 0.0, -a], [a, 0.0, a], [0.0, 0.0, a]])
            f = np.array([[0, 1, 2], [0, 2, 3]])
        return self.to_world(v), f

    def edge(self) -> dict[str, np.ndarray]:
        """The studied edge in world coordinates: direction e (local +z), outward normals of
        face 0 (local +y) and face n, and a vector from the edge into face 0 (local +x)."""
        nn_local = np.array([-np.sin(self.n * np.pi), np.cos(self.n * np.pi), 0.0])
        nn_local = -nn_local if self.n < 2 else np.array([0.0, -1.0, 0.0])
        return {
            "point": self.to_world([0.0, 0.0, 0.0]),
            "e": self.to_world([0.0, 0.0, 1.0]),
            "n0": self.to_world([0.0, 1.0, 0.0]),
            "nn": self.to_world(nn_local),
            "face0_dir": self.to_world([1.0, 0.0, 0.0]),
        }

    def tx(self, sw: Sweep) -> np.ndarray:
        r, p, z = sw.tx_local
        return self.to_world([r * np.cos(p), r * np.sin(p), z])

    def rx(self, sw: Sweep) -> np.ndarray:
        loc = np.stack([sw.rx_rho * np.cos(sw.phi), sw.rx_rho * np.sin(sw.phi),
                        np.full(len(sw.phi), sw.rx_z)], axis=1)
        return self.to_world(loc)


def boundaries(n: float, phi_in: float) -> dict[str, float]:
    """Shadow and reflection boundaries in the exterior (KP: phi = phi' +- pi, pi - phi',
    (2n - 1) pi - phi')."""
    out = {}
    for label, b in (("shadow", phi_in + np.pi), ("shadow", phi_in - np.pi),
                     ("reflection face 0", np.pi - phi_in),
                     ("reflection face n", (2 * n - 1) * np.pi - phi_in)):
        if 0.0 < b < n * np.pi:
            out[label] = float(b)
    return out


def arc(n: float, bounds: dict[str, float], n_arc: int, delta: float) -> np.ndarray:
    """Coarse arc over the exterior (away from the faces) plus samples beside every boundary."""
    edge_gap = np.radians(2.0)
    phi = list(np.linspace(edge_gap, n * np.pi - edge_gap, n_arc))
    for b in bounds.values():
        phi += [b + s * m * delta for m in BOUNDARY_STEPS for s in (-1, 1)]
    return np.array(phi)


def build_scenes(n_arc: int, delta: float, elevation_m: float,
                 solid_thickness_m: float = 10.0) -> dict[str, Canon]:
    """The canonical scenes and their sweeps."""
    rho_tx, rho_rx = 4.0, 3.0
    scenes: dict[str, Canon] = {}

    def wedge(name, title, material, thickness, solid, n, rotation=None, sources=(), truth=None):
        c = Canon(name, title, material, thickness, solid, n, 20.0, truth)
        if rotation is not None:
            c.rotation = rotation
        for lit, phi_in in sources:
            for oblique in (False, True):
                b = boundaries(n, phi_in)
                c.sweeps.append(Sweep(
                    f"{name} / {'obl' if oblique else 'norm'} / src {np.degrees(phi_in):.0f} deg",
                    (rho_tx, phi_in, elevation_m if oblique else 0.0), rho_rx, 0.0,
                    arc(n, b, n_arc, delta), b, lit, oblique, delta))
        scenes[name] = c

    # convex right-angle corner of a box (n = 1.5): a source lighting face 0 only sees the shadow
    # boundary and face 0's reflection boundary; one lighting both faces sees both reflection
    # boundaries
    corner = (("face 0", np.radians(50.0)), ("both faces", np.radians(135.0)))
    wedge("metal_wedge", "metal box corner (n = 1.5)", "metal", 0.002, True, 1.5,
          sources=corner, truth="soft")
    # Sionna: slab coefficients at every face; 10 m of concrete is a half-space to float precision
    # (|exp(-2jq)| ~ 1e-93 at 3.775 GHz), i.e. the Fresnel coefficients hallray uses for solids;
    # --solid-thickness-m 0.1 (Sionna's default thickness) shows the convention's effect
    wedge("concrete_wedge", "concrete box corner (n = 1.5)", "concrete", solid_thickness_m, True,
          1.5, sources=corner)
    # half-planes: thin sheets; vertical edge (vertical polarisation = soft) and horizontal edge
    # (vertical polarisation in the plane of incidence = hard)
    half = (("face 0", np.radians(60.0)),)
    wedge("half_plane_soft", "metal sheet, vertical edge (n = 2, soft)", "metal", 0.002, False,
          2.0, sources=half, truth="soft")
    # local z (edge) -> world y, local y -> world -z: a horizontal sheet, rays in the xz plane
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    wedge("half_plane_hard", "metal sheet, horizontal edge (n = 2, hard)", "metal", 0.002, False,
          2.0, rotation=rot_x, sources=half, truth="hard")
    wedge("wall", "concrete sheet 0.2 m (slab), vertical edge (n = 2)", "concrete", 0.2, False,
          2.0, sources=half)
    return scenes



def write_scene(c: Canon, folder: Path) -> Path:
    """Write ``folder/<name>.xml`` and its mesh (each atomically); returns the XML path."""
    folder.mkdir(parents=True, exist_ok=True)
    v, f = c.mesh()
    ply = folder / f"{c.name}.ply"
    head = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    faces = b"".join(np.uint8(3).tobytes() + tri.astype("<i4").tobytes() for tri in f)
    write_atomic(ply, head.encode() + v.astype("<f4").tobytes() + faces)
    xml = folder / f"{c.name}.xml"
    text = (
        '<scene version="2.1.0">\n'
        f'  <bsdf type="itu-radio-material" id="mat-{c.material}">\n'
        f'    <string name="type" value="{c.material}"/>\n'
        f'    <float name="thickness" value="{c.thickness_m}"/>\n'
        "  </bsdf>\n"
        f'  <shape type="ply" id="{c.name}">\n'
        f'    <string name="filename" value="{ply.name}"/>\n'
        '    <boolean name="face_normals" value="true"/>\n'
        f'    <ref id="mat-{c.material}" name="bsdf"/>\n'
        "  </shape>\n"
        "</scene>\n"
    )
    write_atomic(xml, text.encode("utf-8"))
    return xml
