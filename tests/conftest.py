"""Shared test helpers: small scenes built from code (independent of the bundled files)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from raytrace.physics.materials import MaterialLibrary
from raytrace.scene.model import Scene


def quad(p0, u, v) -> trimesh.Trimesh:
    """An open rectangle (two triangles) with corner p0 and sides u, v."""
    p0, u, v = (np.asarray(x, dtype=float) for x in (p0, u, v))
    verts = np.array([p0, p0 + u, p0 + u + v, p0 + v])
    return trimesh.Trimesh(verts, [[0, 1, 2], [0, 2, 3]], process=False)


def box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    b = trimesh.creation.box(extents=hi - lo)
    b.apply_translation((lo + hi) / 2)
    return b


def make_scene(objects, library: MaterialLibrary | None = None) -> Scene:
    """Scene from ``(name, mesh, material)`` triples."""
    return Scene.from_meshes(list(objects), library or MaterialLibrary.itu())


def assert_same_paths_by_link(a, b, atol_s: float, objects: bool = True) -> None:
    """``a`` and ``b`` hold the same paths: per link and interaction sequence (and the objects
    they meet, with ``objects``), as many, with sorted delays equal to ``atol_s`` seconds.
    Element indices are not compared: a scene read from another file numbers them its own way."""

    def groups(p) -> dict[tuple, list[float]]:
        out: dict[tuple, list[float]] = {}
        for i in range(p.n_paths):
            key = (int(p.tx_index[i]), int(p.rx_index[i]), tuple(p.interaction[i].tolist()))
            key += (tuple(p.objects[i].tolist()),) if objects else ()
            out.setdefault(key, []).append(float(p.delay_s[i]))
        return out

    ga, gb = groups(a), groups(b)
    assert sorted(ga) == sorted(gb), sorted(set(ga) ^ set(gb))[:3]
    for key, delays in ga.items():
        assert len(delays) == len(gb[key]), key
        np.testing.assert_allclose(sorted(gb[key]), sorted(delays), rtol=0, atol=atol_s)


def assert_same_both_ways(fwd, rev, n_a: int, n_b: int, gain_rtol: float = 1e-9) -> None:
    """Every link A -> B of ``fwd`` has the same paths as B -> A of ``rev``: as many, and, sorted
    by delay, the same delays (1e-12 relative) and complex gains (``gain_rtol``). Independent of
    ``raytrace.studies.reciprocity``, which matches paths by their interactions."""
    for t in range(n_a):
        for r in range(n_b):
            p = np.flatnonzero((fwd.tx_index == t) & (fwd.rx_index == r))
            q = np.flatnonzero((rev.tx_index == r) & (rev.rx_index == t))
            assert len(p) == len(q), (t, r)
            p, q = p[np.argsort(fwd.delay_s[p])], q[np.argsort(rev.delay_s[q])]
            np.testing.assert_allclose(rev.delay_s[q], fwd.delay_s[p], rtol=1e-12)
            np.testing.assert_allclose(rev.gain[q], fwd.gain[p], rtol=gain_rtol)


def shoebox_sheets(size=(10.0, 8.0, 3.0), material="concrete"):
    lx, ly, lz = size
    ex, ey, ez = np.eye(3)
    o = np.zeros(3)
    return [
        ("floor", quad(o, lx * ex, ly * ey), material),
        ("ceiling", quad(lz * ez, lx * ex, ly * ey), material),
        ("wall_y0", quad(o, lx * ex, lz * ez), material),
        ("wall_y1", quad(ly * ey, lx * ex, lz * ez), material),
        ("wall_x0", quad(o, ly * ey, lz * ez), material),
        ("wall_x1", quad(lx * ex, ly * ey, lz * ez), material),
    ]


@pytest.fixture
def shoebox() -> Scene:
    return make_scene(shoebox_sheets())


def admit_every_beam(monkeypatch) -> None:
    """Switch the candidate pruning of the tracer off: every beam (cone) reaches every target,
    and the compiled pruning loops (:data:`raytrace.solver.kernels.PRUNE`) return every
    candidate."""
    import raytrace.solver.kernels as kernels
    import raytrace.solver.reflection as refl

    monkeypatch.setattr(kernels, "PRUNE", False)

    def everything(b, target_centre, target_radius):
        shape = np.broadcast(b.apex[..., 0], np.asarray(target_centre)[..., 0], target_radius)
        return np.ones(shape.shape, dtype=bool)

    monkeypatch.setattr(refl, "beam_reaches", everything)
