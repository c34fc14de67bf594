"""Sionna RT, run in its own virtual environment through a small driver that saves its paths."""

from __future__ import annotations

import glob
import json
import os
import re
import subprocess
import time
from pathlib import Path

import numpy as np

from raytrace.core.errors import HallrayError

DEFAULT_SIONNA_PYTHON = "/tmp/sionna-venv/bin/python"


class SionnaError(HallrayError):
    """No Sionna RT to run, or it failed or answered something unexpected (one line, exit 2)."""



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


def llvm_env() -> dict[str, str]:
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
                          text=True, env=llvm_env())
    seconds = time.perf_counter() - t0
    if proc.returncode != 0 or not out.exists():
        lines = [ln for ln in (proc.stderr or "").splitlines() if ln.strip() and not ln[0].isspace()]
        last = lines[-1] if lines else f"exit code {proc.returncode}"
        hint = (" (drjit needs libLLVM >= 16: apt-get install libllvm19)"
                if "Cannot select" in (proc.stderr or "") else "")
        raise SionnaError(f"Sionna RT failed: {last[:300]}{hint}")
    with np.load(out) as z:
        return {k: z[k] for k in z.files}, seconds


