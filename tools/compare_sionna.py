#!/usr/bin/env python3
"""Compare hallray with Sionna RT path by path on canonical wedges (issue 17; docs/fidelity.md).

    python tools/compare_sionna.py --help
    python tools/compare_sionna.py                        # every scene, markdown tables to stdout
    python tools/compare_sionna.py --out /tmp/cmp         # also report.md, results.npz, the scenes
    python tools/compare_sionna.py --scenes half_plane_soft --n-arc 24

What it does, for every canonical scene (built here from code, see ``SCENES``):

1. writes the geometry as PLY meshes plus one Mitsuba / Sionna RT scene XML with ITU-R P.2040
   radio materials; both tools load that same XML (hallray through ``raytrace.load_scene``);
2. runs Sionna RT in its own virtual environment (``--sionna-python``, default
   ``/tmp/sionna-venv/bin/python``; never a hallray dependency) through a small driver written to a
   temporary file, which saves its paths to ``.npz``; and hallray's ``trace`` in this process, on
   the same transmitter and receivers, with the same antennas (isotropic, vertical polarisation
   at both ends), mechanisms (line of sight, one reflection, one diffraction; no penetration) and
   materials;
3. matches the paths of the two tools by interaction type and vertex, and tabulates gain and
   phase differences per mechanism;
4. checks the total field of each tool (line of sight + reflections + the diffraction at the
   wedge's edge) for a jump at every shadow and reflection boundary of every sweep, and compares
   it, for the perfectly conducting wedges (corner and half-planes), with the exact solution for a
   point source (Biot-Tolstoy-Medwin, :func:`wedge_exact`, checked here to satisfy the Helmholtz
   equation, the boundary conditions and continuity);
5. explains the diffraction differences with a numpy transcription of Sionna's diffraction matrix
   (``sionna_diffraction_gain``, its source lines cited there), first checked against Sionna's own
   output, then changed one ingredient at a time into hallray's coefficient.

A maintainers' script: not installed, not run by CI or pytest. Sionna RT 2.2 needs an LLVM of
version 16 or later for its CPU back end (Debian 12: ``apt-get install libllvm19``; with LLVM 14
or 15, drjit stops with "Cannot select ... fmaximum").
"""

from __future__ import annotations

import argparse
import functools
import glob
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from raytrace import TraceConfig, load_scene, trace  # noqa: E402
from raytrace.cli.harness import OneLineParser, run_tool  # noqa: E402
from raytrace.core.constants import C0  # noqa: E402
from raytrace.core.errors import HallrayError  # noqa: E402
from raytrace.physics.materials import fresnel, permittivity, slab  # noqa: E402
from raytrace.physics.utd import (  # noqa: E402
    diffracted_field,
    face_reflection_matrix,
    face_rule_angle,
    transition_function,
    wedge_geometry,
)

DEFAULT_SIONNA_PYTHON = "/tmp/sionna-venv/bin/python"


class SionnaError(HallrayError):
    """No Sionna RT to run, or it failed or answered something unexpected (one line, exit 2)."""


#: Paths of the two tools are the same path when their vertices agree to this (m); Sionna works
#: in float32 (about 1e-6 m at 20 m).
MATCH_TOL_M = 5e-3
#: A diffraction vertex within this of the studied edge's line is "at the edge" (m).
EDGE_TOL_M = 1e-3
#: Receivers on either side of a boundary, at these multiples of --delta-rad from it: the total
#: field is extrapolated to the boundary from each side (quadratic through three samples), so a
#: smooth field gives no step whatever the interference pattern's slope.
BOUNDARY_STEPS = (1, 2, 3)

# =================================================================================================
# canonical scenes, built from code
# =================================================================================================


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


def _boundaries(n: float, phi_in: float) -> dict[str, float]:
    """Shadow and reflection boundaries in the exterior (KP: phi = phi' +- pi, pi - phi',
    (2n - 1) pi - phi')."""
    out = {}
    for label, b in (("shadow", phi_in + np.pi), ("shadow", phi_in - np.pi),
                     ("reflection face 0", np.pi - phi_in),
                     ("reflection face n", (2 * n - 1) * np.pi - phi_in)):
        if 0.0 < b < n * np.pi:
            out[label] = float(b)
    return out


def _arc(n: float, bounds: dict[str, float], n_arc: int, delta: float) -> np.ndarray:
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
                b = _boundaries(n, phi_in)
                c.sweeps.append(Sweep(
                    f"{name} / {'obl' if oblique else 'norm'} / src {np.degrees(phi_in):.0f} deg",
                    (rho_tx, phi_in, elevation_m if oblique else 0.0), rho_rx, 0.0,
                    _arc(n, b, n_arc, delta), b, lit, oblique, delta))
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


# =================================================================================================
# export: PLY + Mitsuba XML, read by both tools
# =================================================================================================
def write_scene(c: Canon, folder: Path) -> Path:
    """Write ``folder/<name>.xml`` and its mesh; returns the XML path."""
    folder.mkdir(parents=True, exist_ok=True)
    v, f = c.mesh()
    ply = folder / f"{c.name}.ply"
    with open(ply, "wb") as fh:
        head = (
            "ply\nformat binary_little_endian 1.0\n"
            f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
            f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
        )
        fh.write(head.encode())
        fh.write(v.astype("<f4").tobytes())
        for tri in f:
            fh.write(np.uint8(3).tobytes() + tri.astype("<i4").tobytes())
    xml = folder / f"{c.name}.xml"
    xml.write_text(
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
    return xml


# =================================================================================================
# Sionna RT, in its own venv
# =================================================================================================
SIONNA_DRIVER = r'''
"""Sionna RT driver written by hallray's tools/compare_sionna.py (runs in Sionna's venv)."""
import json, sys, time
import numpy as np
spec = json.load(open(sys.argv[1]))
import mitsuba as mi
import sionna.rt as rt
out = {"versions": json.dumps({"sionna_rt": getattr(rt, "__version__", "?"),
                                "mitsuba": mi.__version__, "variant": mi.variant()})}
solver = rt.PathSolver(deterministic=True)
for sc in spec["scenes"]:
    scene = rt.load_scene(sc["xml"])
    scene.frequency = spec["frequency_hz"]
    scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    scene.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    for k, sw in enumerate(sc["sweeps"]):
        for name in list(scene.transmitters):
            scene.remove(name)
        for name in list(scene.receivers):
            scene.remove(name)
        scene.add(rt.Transmitter("tx", position=mi.Point3f(*[float(x) for x in sw["tx"]])))
        for i, p in enumerate(sw["rx"]):
            scene.add(rt.Receiver(f"rx{i:05d}", position=mi.Point3f(*[float(x) for x in p])))
        t0 = time.perf_counter()
        paths = solver(scene, max_depth=1, los=True, specular_reflection=True,
                       diffuse_reflection=False, refraction=False, diffraction=True,
                       edge_diffraction=True, diffraction_lit_region=True,
                       samples_per_src=spec["samples"], seed=spec["seed"])
        a_re, a_im = paths.a
        a = (np.array(a_re) + 1j * np.array(a_im)).reshape(len(sw["rx"]), -1)
        key = f"{sc['name']}|{k}"
        out[key + "|a"] = a
        out[key + "|tau"] = np.array(paths.tau).reshape(len(sw["rx"]), -1)
        out[key + "|type"] = np.array(paths.interactions).reshape(-1, len(sw["rx"]), a.shape[1])
        out[key + "|vertex"] = np.array(paths.vertices).reshape(-1, len(sw["rx"]), a.shape[1], 3)
        out[key + "|valid"] = np.array(paths.valid).reshape(len(sw["rx"]), -1)
        out[key + "|seconds"] = np.array(time.perf_counter() - t0)
np.savez(sys.argv[2], **out)
'''


def _llvm_env() -> dict[str, str]:
    """Environment for the Sionna process: point drjit at the newest libLLVM >= 16 if the user
    did not choose one (drjit may otherwise pick an LLVM 14/15 that cannot compile Sionna 2.2)."""
    env = dict(os.environ)
    if "DRJIT_LIBLLVM_PATH" not in env:
        found = []
        for p in glob.glob("/usr/lib/*/libLLVM-*.so") + glob.glob("/usr/lib/llvm-*/lib/libLLVM*.so"):
            m = re.search(r"LLVM-(\d+)\.so$", p) or re.search(r"llvm-(\d+)/", p)
            if m and int(m.group(1)) >= 16:
                found.append((int(m.group(1)), p))
        if found:
            env["DRJIT_LIBLLVM_PATH"] = max(found)[1]
    return env


def run_sionna(python: str, jobs: list[dict], frequency_hz: float, samples: int, seed: int,
               workdir: Path) -> tuple[dict[str, np.ndarray], float]:
    """Run the driver once for every scene; returns its arrays and the wall time (s)."""
    spec = {"scenes": jobs, "frequency_hz": frequency_hz, "samples": samples, "seed": seed}
    spec_path = workdir / "sionna_job.json"
    spec_path.write_text(json.dumps(spec))
    driver = workdir / "sionna_driver.py"
    driver.write_text(SIONNA_DRIVER)
    out = workdir / "sionna_paths.npz"
    t0 = time.perf_counter()
    proc = subprocess.run([python, str(driver), str(spec_path), str(out)], capture_output=True,
                          text=True, env=_llvm_env())
    seconds = time.perf_counter() - t0
    if proc.returncode != 0 or not out.exists():
        lines = [ln for ln in (proc.stderr or "").splitlines() if ln.strip() and not ln[0].isspace()]
        last = lines[-1] if lines else f"exit code {proc.returncode}"
        hint = (" (drjit needs libLLVM >= 16: apt-get install libllvm19)"
                if "Cannot select" in (proc.stderr or "") else "")
        raise SionnaError(f"Sionna RT failed: {last[:300]}{hint}")
    with np.load(out) as z:
        return {k: z[k] for k in z.files}, seconds


# =================================================================================================
# path tables of the two tools
# =================================================================================================
@dataclass
class PathTable:
    """Paths of one sweep: receiver index, kind ("LoS", "R", "D"), vertex, gain (complex field
    ratio including exp(-j k length)), delay."""

    rx: np.ndarray
    kind: np.ndarray
    vertex: np.ndarray
    gain: np.ndarray
    delay: np.ndarray
    element: np.ndarray | None = None  # hallray: wedge / facet index of the first interaction


def sionna_table(res: dict[str, np.ndarray], key: str, frequency_hz: float) -> PathTable:
    a, tau, typ = res[key + "|a"], res[key + "|tau"], res[key + "|type"][0]
    vert, valid = res[key + "|vertex"][0], res[key + "|valid"]
    r, p = np.nonzero(valid & (np.abs(a) > 0))
    kinds = {0: "LoS", 1: "R", 8: "D"}
    t = typ[r, p]
    if np.any(~np.isin(t, list(kinds))):
        raise SionnaError(f"unexpected Sionna interaction types {set(t.tolist())}")
    # Sionna's a excludes the propagation phase; the channel is a exp(-j 2 pi f tau)
    g = a[r, p] * np.exp(-2j * np.pi * frequency_hz * tau[r, p].astype(float))
    v = vert[r, p].astype(float)
    kind = np.array([kinds[int(x)] for x in t])
    v[kind == "LoS"] = np.nan
    return PathTable(r, kind, v, g, tau[r, p].astype(float))


def hallray_table(paths) -> PathTable:
    first = paths.interaction[:, 0] if paths.interaction.shape[1] else np.zeros(paths.n_paths)
    kinds = {0: "LoS", 1: "R", 3: "D"}
    kind = np.array([kinds[int(x)] for x in first])
    v = (paths.points[:, 0] if paths.points.shape[1] else np.full((paths.n_paths, 3), np.nan))
    el = paths.elements[:, 0] if paths.elements.shape[1] else np.full(paths.n_paths, -1)
    return PathTable(paths.rx_index.copy(), kind, v.copy(), paths.gain.copy(),
                     paths.delay_s.copy(), el.copy())


def match(h: PathTable, s: PathTable) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (index in h, index in s) of the same path: same receiver and kind, vertices within
    MATCH_TOL_M (nearest first). Unmatched paths are the complement."""
    hi, si = [], []
    for r in np.unique(np.concatenate([h.rx, s.rx])):
        for kind in ("LoS", "R", "D"):
            a = np.nonzero((h.rx == r) & (h.kind == kind))[0]
            b = np.nonzero((s.rx == r) & (s.kind == kind))[0]
            if not len(a) or not len(b):
                continue
            if kind == "LoS":
                hi.append(a[0])
                si.append(b[0])
                continue
            d = np.linalg.norm(h.vertex[a][:, None] - s.vertex[b][None], axis=2)
            used = set()
            for i in np.argsort(d.min(axis=1)):
                j = int(np.argmin(np.where(np.isin(np.arange(len(b)), list(used)), np.inf, d[i])))
                if d[i, j] < MATCH_TOL_M and j not in used:
                    used.add(j)
                    hi.append(a[i])
                    si.append(b[j])
    return np.array(hi, int), np.array(si, int)


# =================================================================================================
# field models: antennas, exact half-plane, Sionna's diffraction matrix in numpy
# =================================================================================================
def vpol(direction: np.ndarray) -> np.ndarray:
    """Vertical polarisation of an isotropic antenna for a ray along ``direction``: z made
    perpendicular to the ray (hallray's convention; Sionna's "V" is -theta_hat, the same vector
    up to a sign that cancels between the two ends)."""
    d = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    v = np.array([0.0, 0.0, 1.0]) - d[..., 2:3] * d
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


# exact solution of the perfectly conducting wedge for a point source (Biot-Tolstoy-Medwin)
@functools.lru_cache(maxsize=4)
def _eta_grid(k: float, eta_max: float = 7.0) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature grid in eta and trapezoid weights: geometric from 1e-8 to 1e-2 (resolves the
    Lorentzian peak of a term whose boundary is 1e-5 rad away), then uniform to 7 with steps of
    2e-5 at 3.775 GHz, scaled with 1/k (< 0.1 rad of phase per step 3-4 m from the edge); the
    tail beyond eta = 7 is ~1e-6 of the field."""
    step = 2e-5 * 79.1 / k
    eta = np.concatenate([[0.0], np.geomspace(1e-8, 1e-2, 2000), np.arange(1e-2, eta_max, step)[1:]])
    w = np.zeros_like(eta)
    d = np.diff(eta)
    w[:-1] += d / 2
    w[1:] += d / 2
    return eta, w


def wedge_exact(src: np.ndarray, dst: np.ndarray, k: float, n: float, soft: bool) -> np.ndarray:
    """Exact total field of a point source ``exp(-j k R) / R`` beside a perfectly conducting
    (soft: Dirichlet, hard: Neumann) infinite wedge, local frame (edge on the z axis, face 0 at
    phi = 0, air at 0 < phi < n pi, ``n >= 1``): geometrical optics (direct field and the two
    single reflections where visible, images with sign -1 soft / +1 hard) plus the exact edge
    term of Biot and Tolstoy (J. Acoust. Soc. Am. 29, 381, 1957) in the form of Svensson, Fred,
    Vanderkooy (J. Acoust. Soc. Am. 106, 2331, 1999, eq. 3), transformed to frequency with
    ``eta`` as variable (``c t = l(eta)``):

        u_d = -(nu / 2 pi) int_0^inf sum_i eps_i beta_i(eta) exp(-j k l) / l d eta
        beta_i = sin(nu phi_i) / (cosh(nu eta) - cos(nu phi_i)),  nu = 1 / n
        phi_i = pi +- phi' +- phi,  l = sqrt(rho^2 + rho'^2 + (z - z')^2 + 2 rho rho' cosh eta)

    ``eps_i = -1`` for soft on the two image terms (phi' + phi). Its stationary point reproduces
    Keller's diffraction coefficient, which fixes the factor ``nu / 2 pi`` for this source
    normalisation. Checked in :func:`check_exact` (Helmholtz residual, both boundary conditions,
    continuity across every boundary).

    Parameters
    ----------
    src : (3,) float, m; dst : (P, 3) float, m (local frame)

    Returns
    -------
    (P,) complex
    """
    dst = np.atleast_2d(dst)
    rho_s, phi_s = np.hypot(src[0], src[1]), np.arctan2(src[1], src[0]) % (2 * np.pi)
    rho = np.hypot(dst[:, 0], dst[:, 1])
    phi = np.arctan2(dst[:, 1], dst[:, 0]) % (2 * np.pi)
    dz = dst[:, 2] - src[2]
    r_img = -1.0 if soft else 1.0
    nu = 1.0 / n
    # geometrical optics: direct, face 0 image (-phi'), face n image (2 n pi - phi')
    out = np.zeros(len(dst), complex)
    for img_phi, sign, lit in (
        (phi_s, 1.0, np.abs(phi - phi_s) < np.pi),
        (-phi_s, r_img, phi + phi_s < np.pi),
        (2 * n * np.pi - phi_s, r_img, phi + phi_s > (2 * n - 1) * np.pi),
    ):
        r = np.sqrt(rho**2 + rho_s**2 - 2 * rho * rho_s * np.cos(phi - img_phi) + dz**2)
        out += np.where(lit, sign * np.exp(-1j * k * r) / r, 0.0)
    eta, w = _eta_grid(float(k))
    ch, cnh = np.cosh(eta), np.cosh(nu * eta)
    for p in range(len(dst)):
        ell = np.sqrt(rho[p] ** 2 + rho_s**2 + dz[p] ** 2 + 2 * rho[p] * rho_s * ch)
        acc = np.zeros_like(eta)
        for ang, eps in ((np.pi + phi_s + phi[p], r_img), (np.pi + phi_s - phi[p], 1.0),
                         (np.pi - phi_s + phi[p], 1.0), (np.pi - phi_s - phi[p], r_img)):
            acc = acc + eps * np.sin(nu * ang) / (cnh - np.cos(nu * ang))
        out[p] += -nu / (2 * np.pi) * np.sum(w * acc * np.exp(-1j * k * ell) / ell)
    return out


def exact_ratio(src: np.ndarray, dst: np.ndarray, k: float, n: float, soft: bool) -> np.ndarray:
    """Exact total field of the scalar point source over its free-space field ``exp(-j k R)/R``
    (soft: Dirichlet, the field component along the edge; hard: Neumann, the magnetic one)."""
    r = np.linalg.norm(dst - src, axis=-1)
    return wedge_exact(src, dst, k, n, soft) / (np.exp(-1j * k * r) / r)


def check_exact(k: float, n_points: int = 24) -> dict[str, float]:
    """Independent checks of :func:`wedge_exact` (n = 1.5 and 2, soft and hard, an elevated
    source): the 3-D Helmholtz residual (7-point stencil, step lambda/100, truncation ~3e-4)
    relative to ``k^2 |G|`` at random points; the boundary condition on both faces (value,
    soft; one-sided normal derivative relative to ``k |G|``, hard); the step across each shadow
    and reflection boundary (extrapolated to it from samples 1e-4, 2e-4, 3e-4 rad either side, as
    for the tools; relative to |G|)."""
    rng = np.random.default_rng(17)
    out: dict[str, float] = {}
    h = 2 * np.pi / k / 100
    for n in (1.5, 2.0):
        src = np.array([4.0 * np.cos(0.9), 4.0 * np.sin(0.9), 1.0])

        def g0(d, src=src):
            return np.exp(-1j * k * np.linalg.norm(d - src, axis=-1)) / np.linalg.norm(d - src, axis=-1)

        rho, ph = rng.uniform(2, 4, n_points), rng.uniform(0.2, n * np.pi - 0.2, n_points)
        z = rng.uniform(-1, 1, n_points)
        pts = np.stack([rho * np.cos(ph), rho * np.sin(ph), z], 1)
        for soft in (True, False):
            tag = f"n={n:g} {'soft' if soft else 'hard'}"
            u0 = wedge_exact(src, pts, k, n, soft)
            lap = -6 * u0
            for ax in range(3):
                d = np.zeros(3)
                d[ax] = h
                lap = lap + wedge_exact(src, pts + d, k, n, soft) + wedge_exact(src, pts - d, k, n, soft)
            res = np.abs(lap / h**2 + k**2 * u0) / (k**2 * np.abs(g0(pts)))
            out[f"helmholtz {tag}"] = float(np.max(res))
            worst = 0.0
            for ang in (1e-9, n * np.pi - 1e-9):  # on face 0 and face n
                t = np.array([np.cos(ang), np.sin(ang), 0.0])
                nrm = np.array([-np.sin(ang), np.cos(ang), 0.0]) * (1 if ang < 1 else -1)
                on = rho[:, None] * t + z[:, None] * np.array([0.0, 0.0, 1.0])
                if soft:
                    val = np.abs(wedge_exact(src, on, k, n, soft)) / np.abs(g0(on))
                else:
                    u = [wedge_exact(src, on + j * h * nrm, k, n, soft) for j in range(3)]
                    val = np.abs(-3 * u[0] + 4 * u[1] - u[2]) / (2 * h) / (k * np.abs(g0(on)))
                worst = max(worst, float(np.max(val)))
            out[f"boundary condition {tag}"] = worst
            jumps = []
            for b in _boundaries(n, 0.9).values():
                sides = []
                for sgn in (-1, 1):
                    q = np.array([[3.0 * np.cos(b + sgn * m * 1e-4), 3.0 * np.sin(b + sgn * m * 1e-4),
                                   0.0] for m in BOUNDARY_STEPS])
                    sides.append(_extrapolate(wedge_exact(src, q, k, n, soft)))
                jumps.append(abs(sides[1] - sides[0]) / abs(g0(np.array([[3.0, 0.0, 0.0]])))[0])
            out[f"jump at boundaries {tag}"] = float(max(jumps))
    return out


def _rotator(k, s_cur, s_tgt):
    """Sionna's jones_matrix_rotator (utils/jones.py lines 70-91): components in the basis
    (s_cur, k x s_cur) -> (s_tgt, k x s_tgt)."""
    c = _dot(s_cur, s_tgt)
    s = _dot(k, np.cross(s_cur, s_tgt))
    return np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], -2)


def sionna_diffraction_gain(tx, q, rx, e, na, nb, refl, k, grouping="sionna", faces="sionna"):
    """Gain of a diffracted path tx -> q -> rx as Sionna RT 2.2 computes it, in numpy float64.

    A transcription of ``RadioMaterial._diffraction_matrix``
    (sionna/rt/radio_materials/radio_material.py lines 997-1192) with the face labelling of
    ``sample_wedge_diffraction_point`` (utils/wedges.py line 276: face 0 is a face the source
    lights), the field calculator's spreading ``1/sqrt(s s' (s + s'))`` and ``lambda / sqrt(4 pi)``
    receive scaling (path_solvers/field_calculator.py lines 356-365, 425), and isotropic
    vertically polarised antennas at both ends.

    Parameters
    ----------
    tx, q, rx : (P, 3) float, m; transmitter, diffraction point, receiver
    e : (P, 3) float; edge direction with ``na x e`` pointing into face a
    na, nb : (P, 3) float; outward normals of the two faces
    refl : callable(cos_theta) -> (r_te, r_tm); the face's reflection coefficients
    k : float, rad/m
    grouping : "sionna" for ``R_0 (D1 - D4) + R_n (D2 - D3)`` (lines 1167-1176), or "kp" for
        Kouyoumjian-Pathak / Luebbers' ``-(D1 + D2) I + D4 R_0 + D3 R_n`` with the same matrices
    faces : "sionna" for Sionna's face matrices (the incident ray's reflection, and ``R_n = -I``
        when the source does not light face n, lines 1162-1165), or "d8a": hallray's, both faces
        at the angle of the face rule (D8a, the specular reflection between the two ends, each
        taken in front of the face) in the construction of
        :func:`raytrace.physics.utd.face_reflection_matrix`

    Returns
    -------
    (P,) complex, field ratio including exp(-j k (s + s'))
    """
    ki, ko = _unit(q - tx), _unit(rx - q)
    s_p, s = np.linalg.norm(q - tx, axis=1), np.linalg.norm(rx - q, axis=1)
    swap = _dot(ki, na) > 0  # utils/wedges.py line 276
    n0 = np.where(swap[:, None], nb, na)
    nn = np.where(swap[:, None], na, nb)
    e = np.where(swap[:, None], -e, e)
    beta0 = np.arccos(np.clip(np.abs(_dot(ki, e)), 0, 1))
    ext = 2 * np.pi - np.arccos(np.clip(-_dot(n0, nn), -1, 1))
    t0 = _unit(np.cross(n0, e))
    kip = _unit(ki - _dot(ki, e)[:, None] * e)
    kop = _unit(ko - _dot(ko, e)[:, None] * e)
    phi_p = (np.pi - np.arccos(np.clip(-_dot(kip, t0), -1, 1))) * -np.sign(-_dot(kip, n0)) + np.pi
    phi = (np.pi - np.arccos(np.clip(_dot(kop, t0), -1, 1))) * -np.sign(_dot(kop, n0)) + np.pi
    ell = s * s_p / (s + s_p) * np.sin(beta0) ** 2
    n = ext / np.pi

    def a_pm(beta):
        n_p = np.round((beta + np.pi) / (2 * ext))
        n_m = np.round((beta - np.pi) / (2 * ext))
        return 2 * np.cos(ext * n_p - beta / 2) ** 2, 2 * np.cos(ext * n_m - beta / 2) ** 2

    a1, a2 = a_pm(phi - phi_p)
    a3, a4 = a_pm(phi + phi_p)
    fac = -np.exp(-0.25j * np.pi) / (2 * n * np.sqrt(2 * np.pi * k) * np.sin(beta0))

    def cf(psi, x):
        return np.cos(psi) / np.sin(psi) * transition_function(x)

    d1 = fac * cf((np.pi + phi - phi_p) / (2 * n), k * ell * a1)
    d2 = fac * cf((np.pi - (phi - phi_p)) / (2 * n), k * ell * a2)
    d3 = fac * cf((np.pi + phi + phi_p) / (2 * n), k * ell * a3)
    d4 = fac * cf((np.pi - (phi + phi_p)) / (2 * n), k * ell * a4)

    k_sb0 = ki - 2 * _dot(ki, n0)[:, None] * n0
    k_sbn = _unit(ki - 2 * _dot(ki, nn)[:, None] * nn)
    phi_hat_p = _unit(np.cross(ki, e))
    phi_sb0 = -_unit(np.cross(k_sb0, e))
    phi_sbn = -_unit(np.cross(k_sbn, e))
    phi_hat = -_unit(np.cross(ko, e))
    es0, esn = _unit(np.cross(ki, n0)), _unit(np.cross(ki, nn))

    def face(k_sb, es, phi_sb, nrm):
        r_te, r_tm = refl(np.abs(_dot(ki, nrm)))
        dia = np.zeros((len(ki), 2, 2), complex)
        dia[:, 0, 0], dia[:, 1, 1] = r_te, r_tm
        return _rotator(k_sb, es, phi_sb) @ dia @ _rotator(ki, phi_hat_p, es)

    r0 = face(k_sb0, es0, phi_sb0, n0)
    rn = face(k_sbn, esn, phi_sbn, nn)
    if faces == "sionna":
        rn[ext > np.pi + phi_p] = -np.eye(2)
    else:
        # D8a: each face reflects at the in-plane angle of the specular reflection off its plane
        # between the two ends (each mirrored in front of it); hallray's face matrix, reordered
        # from (beta0, phi) to Sionna's (phi, beta0) components; face n's edge direction is -e
        def d8a(a_in, a_out, sign):
            psi = face_rule_angle(a_in, a_out, s_p, s)
            r_te, r_tm = refl(np.sin(beta0) * np.abs(np.sin(psi)))
            return face_reflection_matrix(r_te, r_tm, _dot(ki, sign * e), psi)[:, ::-1, ::-1]

        r0, rn = d8a(phi_p, phi, 1.0), d8a(ext - phi_p, ext - phi, -1.0)
    eye = np.broadcast_to(np.eye(2), r0.shape)
    if grouping == "sionna":
        jm = r0 * (d1 - d4)[:, None, None] + rn * (d2 - d3)[:, None, None]
    else:
        jm = -eye * (d1 + d2)[:, None, None] + r0 * d4[:, None, None] + rn * d3[:, None, None]
    e_in = vpol(ki)
    comp_in = np.stack([_dot(e_in, phi_hat_p), _dot(e_in, np.cross(ki, phi_hat_p))], 1)
    comp_out = np.einsum("pij,pj->pi", jm, comp_in)
    e_out = comp_out[:, :1] * phi_hat + comp_out[:, 1:] * np.cross(ko, phi_hat)
    lam = 2 * np.pi / k
    return (lam / (4 * np.pi) * _dot(vpol(ko), e_out)
            * np.exp(-1j * k * (s + s_p)) / np.sqrt(s * s_p * (s + s_p)))


# =================================================================================================
# per-sweep analysis
# =================================================================================================
def _extrapolate(values: np.ndarray) -> complex:
    """Quadratic extrapolation to the boundary from samples at 1, 2, 3 steps from it."""
    return 3 * values[0] - 3 * values[1] + values[2]


def _pol_factor(c: Canon, k_dep: np.ndarray, k_arr: np.ndarray, soft: bool) -> np.ndarray:
    """Sign turning a ray's gain between the tools' isotropic vertical antennas into the scalar
    field of the exact problem (soft: E along the edge; hard: H along the edge). Each ray of a
    perfectly conducting edge keeps its polarisation (soft: along beta0_hat, which is +-the
    antennas' vertical vector for a vertical edge; hard: along phi_hat, in the plane normal to
    the horizontal edge), so its gain is the scalar ray amplitude times the signs of the launch
    and receive projections."""
    e = c.edge()["e"]
    eb = np.broadcast_to(e, k_arr.shape)
    if soft:
        launch = e - (k_dep @ e)[:, None] * k_dep
        return np.sign(_dot(vpol(k_dep), launch) * _dot(vpol(k_arr), eb))
    return np.sign(_dot(vpol(k_dep), np.cross(k_dep, e)) * _dot(np.cross(k_arr, vpol(k_arr)), eb))


@dataclass
class SweepResult:
    canon: Canon
    sweep: Sweep
    tx: np.ndarray
    rx: np.ndarray
    h: PathTable
    s: PathTable
    pair_h: np.ndarray
    pair_s: np.ndarray
    label: np.ndarray  # (M,) mechanism label of each matched pair
    at_edge: np.ndarray  # (M,) bool, diffraction at the studied edge
    model: dict[str, np.ndarray]  # Sionna-transcription variants, every matched D path
    total: dict[str, np.ndarray]  # tool -> (R,) complex normalised total field
    go: dict[str, np.ndarray]
    exact: np.ndarray | None


def _local_paths(c: Canon, t: PathTable, tx: np.ndarray, rx: np.ndarray) -> np.ndarray:
    """Paths that make the canonical wedge's field: LoS, reflections, diffraction at the edge."""
    ed = c.edge()
    at_edge = np.zeros(len(t.kind), bool)
    d = t.kind == "D"
    rel = t.vertex[d] - ed["point"]
    off = rel - np.outer(rel @ ed["e"], ed["e"])
    at_edge[d] = np.linalg.norm(off, axis=1) < EDGE_TOL_M
    return (t.kind != "D") | at_edge


def _directions(t: PathTable, tx: np.ndarray, rx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    end = rx[t.rx]
    los = np.isnan(t.vertex[:, 0])
    first = np.where(los[:, None], end, t.vertex)
    k_dep = _unit(first - tx)
    k_arr = np.where(los[:, None], k_dep, _unit(np.where(los[:, None], end + 1.0, end) - first))
    return k_dep, k_arr


def analyse(c: Canon, sw: Sweep, h: PathTable, s: PathTable, f_hz: float,
            scene) -> SweepResult:
    k = 2 * np.pi * f_hz / C0
    lam = C0 / f_hz
    tx, rx = c.tx(sw), c.rx(sw)
    ph, ps = match(h, s)
    local_h = _local_paths(c, h, tx, rx)
    at_edge = (h.kind[ph] == "D") & local_h[ph]
    model_kind = f"{'slab' if not c.solid else 'half-space'}"
    labels = []
    for i in ph:
        kind = h.kind[i]
        if kind == "LoS":
            labels.append("LoS")
        elif kind == "R":
            labels.append(f"R {c.material} ({model_kind})")
        elif local_h[i]:
            labels.append(f"D {c.name} / {'oblique' if sw.oblique else 'normal'} / lit: {sw.lit}")
        else:
            labels.append("D other edges")
    labels = np.array(labels, dtype=object)

    # Sionna's coefficient in numpy, and its variants towards hallray's, on every matched D path
    # (the wedge's faces from hallray's scene; e oriented so that normal0 x e points into face 0)
    eta = complex(permittivity(c.material, f_hz))
    model: dict[str, np.ndarray] = {}
    is_d = h.kind[ph] == "D"
    j = ph[is_d]
    if len(j):
        w = scene.wedges
        wi = h.element[j]
        q = h.vertex[j]
        p_tx = np.broadcast_to(tx, q.shape)
        p_rx = rx[h.rx[j]]
        na, nb, f0 = w.normal0[wi], w.normal1[wi], w.face0_dir[wi]
        e = w.direction[wi] * np.sign(_dot(np.cross(na, w.direction[wi]), f0))[:, None]

        def refl_sionna(cos):  # Sionna: slab of the XML thickness on every face
            r_te, r_tm, _, _ = slab(eta, cos, c.thickness_m, f_hz)
            return np.asarray(r_te, complex), np.asarray(r_tm, complex)

        def refl_hallray(cos):  # hallray: Fresnel for solids, slab for sheets
            if c.solid:
                r_te, r_tm, _, _ = fresnel(eta, cos)
                return np.asarray(r_te, complex), np.asarray(r_tm, complex)
            return refl_sionna(cos)

        model["sionna"] = sionna_diffraction_gain(p_tx, q, p_rx, e, na, nb, refl_sionna, k)
        model["kp grouping"] = sionna_diffraction_gain(
            p_tx, q, p_rx, e, na, nb, refl_sionna, k, grouping="kp")
        model["kp grouping, D8a faces"] = sionna_diffraction_gain(
            p_tx, q, p_rx, e, na, nb, refl_hallray, k, grouping="kp", faces="d8a")
        # hallray's own coefficient through its API (the tracer's value, recomputed)
        g = wedge_geometry(p_tx, p_rx, q, e, na, nb, face0_dir=f0)
        fd = diffracted_field(g, vpol(_unit(q - p_tx)).astype(complex), f_hz,
                              r_0=refl_hallray(g.cos_theta_0), r_n=refl_hallray(g.cos_theta_n))
        model["hallray api"] = (lam / (4 * np.pi * g.s_in) * np.exp(-1j * k * g.s_in)
                                * _dot(fd.field, vpol(_unit(p_rx - q))))

    # total fields (normalised by the free-space field at each receiver) and GO only
    r_los = np.linalg.norm(rx - tx, axis=1)
    free = lam / (4 * np.pi * r_los) * np.exp(-1j * k * r_los)
    total, go = {}, {}
    use_truth = c.truth == "soft" or (c.truth == "hard" and not sw.oblique)
    soft = c.truth != "hard"
    for name, t in (("hallray", h), ("sionna", s)):
        keep = _local_paths(c, t, tx, rx)
        k_dep, k_arr = _directions(t, tx, rx)
        fac = _pol_factor(c, k_dep, k_arr, soft) if use_truth else np.ones(len(t.kind))
        los_dir = _unit(rx - tx)
        fac_free = (_pol_factor(c, los_dir, los_dir, soft) if use_truth else np.ones(len(rx)))
        contrib = np.where(keep, fac * t.gain, 0.0)
        total[name] = np.bincount(t.rx, contrib.real, len(rx)) + 1j * np.bincount(
            t.rx, contrib.imag, len(rx))
        total[name] = total[name] / (fac_free * free)
        contrib_go = np.where(keep & (t.kind != "D"), fac * t.gain, 0.0)
        go[name] = (np.bincount(t.rx, contrib_go.real, len(rx)) + 1j * np.bincount(
            t.rx, contrib_go.imag, len(rx))) / (fac_free * free)
    exact = None
    if use_truth:
        src_l = c.from_world(tx)
        exact = exact_ratio(src_l, c.from_world(rx), k, c.n, soft)
    return SweepResult(c, sw, tx, rx, h, s, ph, ps, labels, at_edge, model, total, go, exact)


# =================================================================================================
# report
# =================================================================================================
def _db(x: np.ndarray) -> np.ndarray:
    return 20 * np.log10(np.maximum(np.abs(x), 1e-300))


def _stats(v: np.ndarray) -> str:
    a = np.abs(v)
    return f"{np.median(a):.3g} / {np.quantile(a, 0.9):.3g} / {np.max(a):.3g}"


def _phase_deg(ratio: np.ndarray) -> np.ndarray:
    return np.degrees(np.angle(ratio))


def table_paths(results: list[SweepResult]) -> str:
    """Matched paths per mechanism: Sionna relative to hallray."""
    rows: dict[str, list] = {}
    for r in results:
        gh, gs = r.h.gain[r.pair_h], r.s.gain[r.pair_s]
        for lab in np.unique(r.label):
            sel = r.label == lab
            d = rows.setdefault(lab, [[], [], 0, 0])
            d[0].append(_db(gs[sel]) - _db(gh[sel]))
            d[1].append(_phase_deg(gs[sel] / gh[sel]))
        # unmatched, by kind (diffraction at other edges counted apart)
        for tool, t, used in (("hallray", r.h, r.pair_h), ("sionna", r.s, r.pair_s)):
            rest = np.setdiff1d(np.arange(len(t.kind)), used)
            local = _local_paths(r.canon, t, r.tx, r.rx)
            for i in rest:
                if t.kind[i] == "LoS":
                    lab = "LoS"
                elif t.kind[i] == "R":
                    lab = f"R {r.canon.material} ({'half-space' if r.canon.solid else 'slab'})"
                elif local[i]:
                    lab = (f"D {r.canon.name} / {'oblique' if r.sweep.oblique else 'normal'} / "
                           f"lit: {r.sweep.lit}")
                else:
                    lab = "D other edges"
                d = rows.setdefault(lab, [[], [], 0, 0])
                d[2 if tool == "hallray" else 3] += 1
    out = ["| mechanism | matched | only hallray / only Sionna | gain Sionna - hallray, signed median (dB) "
           "| abs dB median / p90 / max | abs phase median / p90 / max (deg) |",
           "|---|---|---|---|---|---|"]
    for lab in sorted(rows, key=lambda x: (x[0] != "L", x[0] != "R", x)):
        ddb, dph, oh, os_ = rows[lab]
        if ddb:
            a, p = np.concatenate(ddb), np.concatenate(dph)
            out.append(f"| {lab} | {len(a)} | {oh} / {os_} | {np.median(a):+.3g} | {_stats(a)} "
                       f"| {_stats(p)} |")
        else:
            out.append(f"| {lab} | 0 | {oh} / {os_} | | | |")
    return "\n".join(out)


def table_model(results: list[SweepResult]) -> str:
    """Diffraction paths: Sionna's value against its numpy transcription, and the transcription
    changed step by step into hallray's coefficient. Cells: abs dB median / p90 / max; max abs
    phase (deg)."""
    keys = ["Sionna vs transcription", "transcription vs hallray", "+ KP grouping vs hallray",
            "+ face rule (D8a) vs hallray", "hallray API vs hallray trace"]
    rows: dict[str, dict[str, list]] = {}
    for r in results:
        if not len(r.model):
            continue
        is_d = r.h.kind[r.pair_h] == "D"
        gs, gh = r.s.gain[r.pair_s][is_d], r.h.gain[r.pair_h][is_d]
        m = r.model
        pairs = dict(zip(keys, (
            (gs, m["sionna"]), (m["sionna"], gh), (m["kp grouping"], gh),
            (m["kp grouping, D8a faces"], gh), (m["hallray api"], gh)), strict=True))
        for lab in np.unique(r.label[is_d]):
            sel = r.label[is_d] == lab
            d = rows.setdefault(lab, {})
            for key, (x, y) in pairs.items():
                d.setdefault(key, []).append(x[sel] / y[sel])
    out = ["| diffraction | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys)]
    for lab in sorted(rows):
        cells = []
        for key in keys:
            ratio = np.concatenate(rows[lab][key])
            cells.append(f"{_stats(_db(ratio))} dB; {np.max(np.abs(_phase_deg(ratio))):.3g} deg")
        out.append(f"| {lab} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def table_boundaries(results: list[SweepResult]) -> str:
    """Step of the total field across each boundary (quadratic extrapolation from 3 samples each
    side): 20 log10 |T(b+) / T(b-)| in dB, for each tool, the exact solution and GO alone."""
    out = ["| sweep | boundary | hallray (dB) | Sionna (dB) | exact (dB) | GO alone, hallray (dB) |",
           "|---|---|---|---|---|---|"]
    for r in results:
        phi = r.sweep.phi
        for lab, b in r.sweep.boundaries.items():
            cells = []
            series = [r.total["hallray"], r.total["sionna"], r.exact, r.go["hallray"]]
            for v in series:
                if v is None:
                    cells.append("")
                    continue
                sides = []
                for sgn in (-1, 1):
                    idx = [int(np.argmin(np.abs(phi - (b + sgn * m * r.sweep.delta))))
                           for m in BOUNDARY_STEPS]
                    sides.append(_extrapolate(v[idx]))
                step = _db(sides[1] / sides[0])
                cells.append(f"{step:+.3f}" if abs(step) < 300 else ("-inf" if step < 0 else "+inf"))
            out.append(f"| {r.sweep.name} | {lab} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def table_truth(results: list[SweepResult]) -> str:
    """Total field of each tool against the exact solution."""
    out = ["| sweep | tool | abs dB median / p90 / max | abs phase median / p90 / max (deg) |",
           "|---|---|---|---|"]
    for r in results:
        if r.exact is None:
            continue
        for tool in ("hallray", "sionna"):
            ratio = r.total[tool] / r.exact
            out.append(f"| {r.sweep.name} | {tool} | {_stats(_db(ratio))} | "
                       f"{_stats(_phase_deg(ratio))} |")
    return "\n".join(out)


# =================================================================================================
# command line
# =================================================================================================
def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(
        description="Compare hallray with Sionna RT path by path on canonical wedges (issue 17).")
    ap.add_argument("--sionna-python", default=os.environ.get("SIONNA_PYTHON", DEFAULT_SIONNA_PYTHON),
                    help="python of the venv with sionna-rt (default $SIONNA_PYTHON or "
                         f"{DEFAULT_SIONNA_PYTHON})")
    ap.add_argument("--frequency-hz", type=float, default=3.775e9)
    ap.add_argument("--scenes", default="all",
                    help="comma-separated subset of: metal_wedge, concrete_wedge, "
                         "half_plane_soft, half_plane_hard, wall (default all)")
    ap.add_argument("--n-arc", type=int, default=24,
                    help="receivers per sweep on the arc, besides 6 per boundary (default 24)")
    ap.add_argument("--delta-rad", type=float, default=3e-4,
                    help="spacing of the samples beside each boundary, rad (default 3e-4)")
    ap.add_argument("--elevation-m", type=float, default=3.0,
                    help="height of the source of the oblique sweeps above the receivers (m)")
    ap.add_argument("--solid-thickness-m", type=float, default=10.0,
                    help="slab thickness Sionna gives the concrete box (hallray: half-space for a "
                         "solid); default 10 m = half-space; 0.1 = Sionna's default")
    ap.add_argument("--samples", type=int, default=10**6, help="Sionna samples per source")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-checks", action="store_true",
                    help="skip the checks of the exact solution (Helmholtz residual etc.)")
    ap.add_argument("--out", type=Path, default=None,
                    help="folder for report.md, results.npz and the exported scenes")
    return ap


def _main(a: argparse.Namespace) -> int:
    if not Path(a.sionna_python).is_file():
        raise SionnaError(f"no Sionna RT python at {a.sionna_python} (create the venv: "
                          "python3 -m venv /tmp/sionna-venv && /tmp/sionna-venv/bin/pip install "
                          "sionna-rt, or pass --sionna-python)")
    if not (np.isfinite(a.frequency_hz) and a.frequency_hz > 0):
        raise HallrayError("--frequency-hz must be positive")
    if a.n_arc < 3 or not (0 < a.delta_rad < 0.01):
        raise HallrayError("--n-arc must be >= 3 and 0 < --delta-rad < 0.01")
    if not (a.solid_thickness_m > 0):
        raise HallrayError("--solid-thickness-m must be positive")
    if not np.isfinite(a.elevation_m):
        raise HallrayError("--elevation-m must be a finite number of metres")
    if a.samples < 1:
        raise HallrayError("--samples must be >= 1")
    if a.out is not None and a.out.exists() and not a.out.is_dir():
        raise HallrayError(f"--out {a.out} exists and is not a folder")
    scenes = build_scenes(a.n_arc, a.delta_rad, a.elevation_m, a.solid_thickness_m)
    names = list(scenes) if a.scenes == "all" else [x.strip() for x in a.scenes.split(",")]
    unknown = [x for x in names if x not in scenes]
    if unknown:
        raise HallrayError(f"unknown scene(s) {', '.join(unknown)} (known: {', '.join(scenes)})")

    with tempfile.TemporaryDirectory(prefix="compare_sionna_") as tmp:
        work = Path(tmp)
        scene_dir = (a.out / "scenes") if a.out else work / "scenes"
        xmls = {nm: write_scene(scenes[nm], scene_dir) for nm in names}
        jobs = [{"name": nm, "xml": str(xmls[nm]),
                 "sweeps": [{"tx": scenes[nm].tx(sw).tolist(), "rx": scenes[nm].rx(sw).tolist()}
                            for sw in scenes[nm].sweeps]} for nm in names]
        n_rx = sum(len(sw.phi) for nm in names for sw in scenes[nm].sweeps)
        print(f"compare_sionna: {len(names)} scene(s), {n_rx} receivers; running Sionna RT ...",
              file=sys.stderr)
        sres, s_seconds = run_sionna(a.sionna_python, jobs, a.frequency_hz, a.samples, a.seed, work)
        # hallray loads the same XML while it still exists (without --out it is in ``work``)
        try:
            loaded = {nm: load_scene(xmls[nm]) for nm in names}
        except HallrayError as exc:
            raise HallrayError(f"hallray: {exc}") from None
    versions = json.loads(str(sres["versions"]))

    results: list[SweepResult] = []
    t0 = time.perf_counter()
    h_seconds = 0.0
    for nm in names:
        c = scenes[nm]
        try:
            scene = loaded[nm]
            for i, sw in enumerate(c.sweeps):
                t1 = time.perf_counter()
                cfg = TraceConfig(max_reflections=1, max_penetrations=0, max_diffractions=1,
                                  max_interactions=1, slab_delay=False)
                paths = trace(scene, c.tx(sw)[None], c.rx(sw), a.frequency_hz, cfg)
                h_seconds += time.perf_counter() - t1
                h = hallray_table(paths)
                s = sionna_table(sres, f"{nm}|{i}", a.frequency_hz)
                results.append(analyse(c, sw, h, s, a.frequency_hz, scene))
        except SionnaError:
            raise
        except HallrayError as exc:
            raise HallrayError(f"hallray: {exc}") from None
    a_seconds = time.perf_counter() - t0 - h_seconds
    k = 2 * np.pi * a.frequency_hz / C0
    checks = {} if a.no_checks else check_exact(k)
    load = os.getloadavg()

    md = [
        f"Sionna RT {versions.get('sionna_rt')} (Mitsuba {versions.get('mitsuba')}, "
        f"{versions.get('variant')}) vs hallray, {a.frequency_hz / 1e9:g} GHz, "
        f"{len(results)} sweeps, {n_rx} receivers; isotropic vertically polarised antennas; "
        "LoS, 1 reflection, 1 diffraction, no penetration.",
        f"Wall time: Sionna {s_seconds:.0f} s (one process, including its start and JIT), hallray "
        f"trace {h_seconds:.1f} s, analysis and exact solution {a_seconds:.0f} s; load average "
        f"{load[0]:.1f} / {load[1]:.1f} on {os.cpu_count()} cores (shared machine: noisy).",
        "",
        "### Matched paths: gain and phase of Sionna relative to hallray",
        "",
        table_paths(results),
        "",
        "### Diffraction at the studied edge: Sionna, its transcription, and the steps to hallray "
        "(abs dB median / p90 / max)",
        "",
        table_model(results),
        "",
        "### Total field against the exact solution (perfectly conducting wedge, point source)",
        "",
        table_truth(results),
        "",
        "### Step of the total field across each boundary",
        "",
        table_boundaries(results),
    ]
    if checks:
        md += ["", "### Checks of the exact solution", "",
               "| check | worst |", "|---|---|"] + [f"| {kk} | {v:.2e} |" for kk, v in checks.items()]
    report = "\n".join(md) + "\n"
    print(report)
    if a.out:
        a.out.mkdir(parents=True, exist_ok=True)
        arrays = {}
        for i, r in enumerate(results):
            pre = f"s{i:02d}_"
            arrays[pre + "name"] = np.array(r.sweep.name)
            arrays[pre + "phi"] = r.sweep.phi
            arrays[pre + "label"] = r.label.astype(str)
            arrays[pre + "gain_hallray"] = r.h.gain[r.pair_h]
            arrays[pre + "gain_sionna"] = r.s.gain[r.pair_s]
            arrays[pre + "rx_index"] = r.h.rx[r.pair_h]
            arrays[pre + "vertex"] = r.h.vertex[r.pair_h]
            for tool in ("hallray", "sionna"):
                arrays[pre + f"total_{tool}"] = r.total[tool]
            if r.exact is not None:
                arrays[pre + "total_exact"] = r.exact
            for key, v in r.model.items():
                arrays[pre + "model_" + key.replace(" ", "_").replace(",", "")] = v
        tmp_npz = a.out / "results.npz.tmp"
        with open(tmp_npz, "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(tmp_npz, a.out / "results.npz")
        (a.out / "report.md").write_text(report)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
