"""One sweep's analysis: matched paths by mechanism, the transcription's variants on every
diffraction path, and the total field of each tool against the exact solution."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sionna_canon import Canon, Sweep
from sionna_paths import PathTable, match
from sionna_utd import dot, sionna_diffraction_gain, unit, vpol
from wedge_exact import exact_ratio

from raytrace.core.constants import C0
from raytrace.physics.materials import fresnel, permittivity, slab
from raytrace.physics.utd import diffracted_field, wedge_geometry

#: A diffraction vertex within this of the studied edge's line is "at the edge" (m).
EDGE_TOL_M = 1e-3


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
        return np.sign(dot(vpol(k_dep), launch) * dot(vpol(k_arr), eb))
    return np.sign(dot(vpol(k_dep), np.cross(k_dep, e)) * dot(np.cross(k_arr, vpol(k_arr)), eb))


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


def local_paths(c: Canon, t: PathTable, tx: np.ndarray, rx: np.ndarray) -> np.ndarray:
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
    k_dep = unit(first - tx)
    k_arr = np.where(los[:, None], k_dep, unit(np.where(los[:, None], end + 1.0, end) - first))
    return k_dep, k_arr


def analyse(c: Canon, sw: Sweep, h: PathTable, s: PathTable, f_hz: float,
            scene) -> SweepResult:
    k = 2 * np.pi * f_hz / C0
    lam = C0 / f_hz
    tx, rx = c.tx(sw), c.rx(sw)
    ph, ps = match(h, s)
    local_h = local_paths(c, h, tx, rx)
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
        e = w.direction[wi] * np.sign(dot(np.cross(na, w.direction[wi]), f0))[:, None]

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
        fd = diffracted_field(g, vpol(unit(q - p_tx)).astype(complex), f_hz,
                              r_0=refl_hallray(g.cos_theta_0), r_n=refl_hallray(g.cos_theta_n))
        model["hallray api"] = (lam / (4 * np.pi * g.s_in) * np.exp(-1j * k * g.s_in)
                                * dot(fd.field, vpol(unit(p_rx - q))))

    # total fields (normalised by the free-space field at each receiver) and GO only
    r_los = np.linalg.norm(rx - tx, axis=1)
    free = lam / (4 * np.pi * r_los) * np.exp(-1j * k * r_los)
    total, go = {}, {}
    use_truth = c.truth == "soft" or (c.truth == "hard" and not sw.oblique)
    soft = c.truth != "hard"
    for name, t in (("hallray", h), ("sionna", s)):
        keep = local_paths(c, t, tx, rx)
        k_dep, k_arr = _directions(t, tx, rx)
        fac = _pol_factor(c, k_dep, k_arr, soft) if use_truth else np.ones(len(t.kind))
        los_dir = unit(rx - tx)
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


