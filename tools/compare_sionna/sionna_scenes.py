"""Sionna RT's own canonical scenes, path by path (``python tools/compare_sionna --sionna-scenes
DIR``): both tools read Sionna's files as they are (hallray as surfaces, Sionna RT's model:
docs/scene.md, "Solids or surfaces"), trace one link each with line of sight, reflections and
transmission up to Sionna's ``max_depth`` interactions, and the paths are matched by their
geometric delay.

hallray's gain carries the free-space phase ``exp(-j k L)`` and a transmitted path's delay the
slab's excess (docs/materials.md, "Delay through a wall"); Sionna's ``a`` carries neither and its
``tau`` is geometric. So the table compares hallray's gain times ``exp(+j k L)`` with ``a``, and
hallray's geometric delay (through its interaction points) with ``tau``; a transmission's phase
also differs by the slab's phase reference (hallray's ``T`` is relative to free space over the
slab, P.2040's printed ``T``, Sionna's, is not: ``k d cos(theta)``).
"""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import numpy as np
from sionna_run import SionnaError, llvm_env

from raytrace import TraceConfig, load_scene, trace
from raytrace.core.constants import C0
from raytrace.core.errors import HallrayError

#: (Sionna scene, transmitter, receiver, max_depth, refraction): one link each, placed so that
#: every mechanism of the scene occurs (the box's antennas inside it).
JOBS = (
    ("box", (1.3, 2.1, 1.4), (-2.2, -0.7, 3.1), 2, False),
    ("simple_reflector", (-1.0, 0.2, 1.0), (1.0, -0.1, 0.7), 1, False),
    ("floor_wall", (-1.2, -0.4, 1.6), (-0.7, 0.9, 1.6), 2, False),
    ("floor_wall", (-1.5, -0.8, 1.2), (-0.4, 1.1, 2.2), 2, False),
    ("box_one_screen", (-2.0, 0.5, 1.5), (2.5, -0.3, 1.5), 2, True),
    ("double_reflector", (-0.2, 0.1, 2.0), (-0.5, -0.1, 4.0), 2, False),
    ("triple_reflector", (-1.0, 0.3, 3.0), (1.0, -0.2, 4.0), 2, False),
    ("box_two_screens", (-3.0, 0.5, 1.5), (3.0, -0.4, 2.0), 2, True),
    ("simple_street_canyon", (-30.0, 0.0, 10.0), (20.0, 5.0, 1.5), 2, True),
)
#: Paths whose geometric delays differ by less than this are the same path, s.
MATCH_S = 1e-12

DRIVER = r'''
import json, sys
import numpy as np
import mitsuba as mi
import sionna.rt as rt
spec = json.load(open(sys.argv[1]))
out = {}
solver = rt.PathSolver()
for k, job in enumerate(spec["jobs"]):
    scene = rt.load_scene(job["xml"])
    scene.frequency = spec["frequency_hz"]
    scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    scene.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    scene.add(rt.Transmitter("tx", position=mi.Point3f(*job["tx"])))
    scene.add(rt.Receiver("rx", position=mi.Point3f(*job["rx"])))
    p = solver(scene, max_depth=job["depth"], los=True, specular_reflection=True,
               diffuse_reflection=False, refraction=job["refraction"], diffraction=False,
               samples_per_src=spec["samples"], seed=spec["seed"])
    a_re, a_im = p.a
    valid = np.array(p.valid).reshape(-1)
    out[f"{k}|a"] = (np.array(a_re) + 1j * np.array(a_im)).reshape(-1)[valid]
    out[f"{k}|tau"] = np.array(p.tau).reshape(-1)[valid]
out["versions"] = json.dumps({"sionna_rt": getattr(rt, "__version__", "?"),
                              "mitsuba": mi.__version__, "variant": mi.variant()})
np.savez(sys.argv[2], **out)
'''


def _xml(folder: Path, name: str) -> Path:
    path = folder / name / f"{name}.xml"
    if not path.is_file():
        raise HallrayError(f"--sionna-scenes: no {name}/{name}.xml in {folder} (the folder of "
                           "sionna-rt's scenes, or tests/data/sionna_rt)")  # fmt: skip
    return path


def run(python: str, folder: Path, frequency_hz: float, samples: int, seed: int,
        workdir: Path) -> tuple[dict, float]:  # fmt: skip
    """Sionna RT's paths of every job (``{k|a, k|tau}``) and its wall time, s."""
    jobs = [{"xml": str(_xml(folder, n)), "tx": list(tx), "rx": list(rx), "depth": d,
             "refraction": r} for n, tx, rx, d, r in JOBS]  # fmt: skip
    spec = workdir / "jobs.json"
    spec.write_text(json.dumps({"jobs": jobs, "frequency_hz": frequency_hz, "samples": samples,
                                "seed": seed}))  # fmt: skip
    driver, out = workdir / "driver.py", workdir / "sionna_scenes.npz"
    driver.write_text(DRIVER)
    t0 = time.perf_counter()
    proc = subprocess.run([python, str(driver), str(spec), str(out)], capture_output=True,
                          text=True, env=llvm_env())  # fmt: skip
    if proc.returncode != 0 or not out.exists():
        lines = [ln for ln in (proc.stderr or "").splitlines() if ln.strip()]
        raise SionnaError(f"Sionna RT failed: {(lines[-1] if lines else proc.returncode)!s:.300}")
    with np.load(out) as z:
        return {k: z[k] for k in z.files}, time.perf_counter() - t0


def _hallray(folder: Path, k: int, frequency_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """hallray's paths of job ``k`` within its depth: geometric delays (s) and gains without the
    free-space phase."""
    name, tx, rx, depth, refraction = JOBS[k]
    scene = load_scene(_xml(folder, name), cache=False)
    cfg = TraceConfig(max_reflections=2, max_penetrations=2 if refraction else 0,
                      max_diffractions=0, max_interactions=depth)  # fmt: skip
    a, b = np.array([tx], float), np.array([rx], float)
    p = trace(scene, a, b, frequency_hz, cfg)
    keep = np.flatnonzero(p.n_reflections + p.n_penetrations + p.n_diffractions <= depth)
    # the chain tx, interaction points, rx; a path's unused (NaN, trailing) points set to rx add
    # segments of zero length
    pts = p.points[keep]
    pts = np.where(np.isfinite(pts).all(axis=2, keepdims=True), pts, b[:, None])
    chain = np.concatenate([np.broadcast_to(a[:, None], (len(keep), 1, 3)), pts,
                            np.broadcast_to(b[:, None], (len(keep), 1, 3))], axis=1)  # fmt: skip
    geo = np.linalg.norm(np.diff(chain, axis=1), axis=2).sum(axis=1) / C0
    return geo, p.gain[keep] * np.exp(2j * np.pi * frequency_hz * geo)


def compare(sres: dict, folder: Path, frequency_hz: float) -> tuple[str, dict]:
    """The markdown table of every matched path and the summary (counts, largest differences)."""
    rows = ["| scene | link | delay [ns] | d delay [ps] | d abs(a) [dB] | d phase [deg] |",
            "|---|---|---|---|---|---|"]  # fmt: skip
    summary = {"matched": 0, "sionna_only": 0, "hallray_only": 0, "max_db": 0.0,
               "max_deg_reflection": 0.0, "max_ps": 0.0}  # fmt: skip
    for k, (name, _tx, _rx, _depth, refraction) in enumerate(JOBS):
        geo, gain = _hallray(folder, k, frequency_hz)
        used: set[int] = set()
        for t, a in sorted(zip(sres[f"{k}|tau"], sres[f"{k}|a"]), key=lambda x: x[0]):
            i = int(np.argmin(np.abs(geo - t))) if len(geo) else -1
            if i < 0 or abs(geo[i] - t) >= MATCH_S or i in used:
                summary["sionna_only"] += 1
                rows.append(f"| {name} | {k} | {t * 1e9:.4f} | Sionna only | | |")
                continue
            used.add(i)
            ddb = 20 * np.log10(abs(gain[i]) / abs(a))
            deg = float(np.degrees(np.angle(gain[i] / a)))
            summary["matched"] += 1
            summary["max_db"] = max(summary["max_db"], abs(ddb))
            summary["max_ps"] = max(summary["max_ps"], abs(geo[i] - t) * 1e12)
            if not refraction:
                summary["max_deg_reflection"] = max(summary["max_deg_reflection"], abs(deg))
            rows.append(f"| {name} | {k} | {t * 1e9:.4f} | {(geo[i] - t) * 1e12:+.3f} | "
                        f"{ddb:+.6f} | {deg:+.4f} |")  # fmt: skip
        for i in sorted(set(range(len(geo))) - used):
            summary["hallray_only"] += 1
            rows.append(f"| {name} | {k} | {geo[i] * 1e9:.4f} | hallray only | | |")
    return "\n".join(rows), summary
