"""The maintainers' tools in tools/: each answers ``--help`` and is listed in docs/tools.md; on bad
input each gives one line ``error: ...`` on stderr, exit status 2, no traceback, nothing written,
and before any real work (each run is mostly interpreter and import time).

The tools are run as subprocesses, as a maintainer runs them (``python tools/NAME.py ...`` from
the checkout, ``python tools/NAME`` for a tool that is a folder), all at once on a thread pool to
keep the file short.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: Seconds a run may take before it counts as having started real work (a run that fails as it
#: should takes a second or two).
TIMEOUT_S = 60

#: case -> (script, arguments, a fragment of the expected message). ``{tmp}`` in an argument is
#: an empty folder of the case's own, which must still be empty afterwards.
CASES: dict[str, tuple[str, list[str], str]] = {
    "bench-negative-grid-step": ("bench.py", ["--grid-step", "-1", "--only-scaling"], "--grid-step"),
    "bench-zero-grid-step": ("bench.py", ["--grid-step", "0", "--only-scaling"], "--grid-step"),
    "bench-zero-repeat": ("bench.py", ["--repeat", "0", "--only-scaling"], "--repeat"),
    "bench-zero-epochs": ("bench.py", ["--epochs", "0", "--no-scaling"], "--epochs"),
    "bench_positioning-not-an-integer": ("bench_positioning.py", ["abc"], "invalid int value"),
    "bench_positioning-zero-epochs": ("bench_positioning.py", ["0"], "n_epochs"),
    "bench_receivers-unknown-receiver": (
        "bench_receivers.py", ["-o", "{tmp}/out", "--receivers", "first-lobe,nope"], "unknown receiver"
    ),
    "bench_receivers-zero-duration": (
        "bench_receivers.py", ["-o", "{tmp}/out", "--duration", "0"], "--duration"
    ),
    "bench_scan-zero-points": ("bench_scan.py", ["--points", "0"], "--points"),
    "bench_twin-missing-dataset": (
        "bench_twin.py", ["--data", "{tmp}/no", "--maps", "{tmp}/no"], "dataset directory not found"
    ),
    "bench_twin-bad-steps": (
        "bench_twin.py", ["--data", "{tmp}", "--maps", "{tmp}", "--steps", "0.05,abc"], "--steps"
    ),
    "bench_scale-too-few-triangles": ("bench_scale.py", ["--max-triangles", "10"], "--max-triangles"),
    "bench_scale-negative-reach": ("bench_scale.py", ["--facet-reach", "-1"], "--facet-reach"),
    "bench_scale-recall-without-reach": ("bench_scale.py", ["--recall"], "give --facet-reach"),
    "smooth_edges-bad-angles": ("smooth_edges.py", ["--angles", "2,abc"], "--angles"),
    "smooth_edges-angle-out-of-range": ("smooth_edges.py", ["--angles", "120"], "smooth angle"),
    "build_scenes-exclusive-options": ("build_scenes.py", ["--check", "--los-table"], "not allowed"),
    "check_layers-missing-root": ("check_layers.py", ["{tmp}/no"], "no raytrace"),
    "check_reciprocity-not-an-integer": (
        "check_reciprocity.py", ["--max-reflections", "two"], "--max-reflections"
    ),
    "check_reciprocity-negative-tolerance": ("check_reciprocity.py", ["--tol-db", "-1"], "--tol-db"),
    "compare_sionna-no-sionna": (
        "compare_sionna", ["--sionna-python", "{tmp}/no/python"], "no Sionna RT python"
    ),
    "make_figures-unknown-option": ("make_figures.py", ["--no-such-option"], "unrecognized"),
    "plot_hall-zero-dpi": ("plot_hall.py", ["--dpi", "0", "-o", "{tmp}/hall.png"], "--dpi"),
    "plot_hall-missing-output-directory": (
        "plot_hall.py", ["-o", "{tmp}/no/hall.png"], "does not exist"
    ),
    "plot_inf-bad-size": ("plot_inf.py", ["--size", "abc", "--out", "{tmp}"], "bad size"),
    "profile_trace-unknown-scene": ("profile_trace.py", ["--scene", "nosuch"], "scene file not found"),
    "profile_trace-negative-grid-step": ("profile_trace.py", ["--grid-step", "-1"], "--grid-step"),
    "trace_identity-missing-reference": (
        "trace_identity.py", ["check", "{tmp}/no/ref.pkl"], "No such file or directory"
    ),
    "trace_identity-missing-output-directory": (
        "trace_identity.py", ["save", "{tmp}/no/ref.pkl"], "does not exist"
    ),
}  # fmt: skip


def _run(script: str, args: list[str], tmp: Path) -> subprocess.CompletedProcess:
    argv = [a.replace("{tmp}", str(tmp)) for a in args]
    return subprocess.run(
        [sys.executable, str(Path("tools") / script), *argv],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        stdin=subprocess.DEVNULL,
    )


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """case -> (future of its CompletedProcess, its folder); every case started at once."""
    workers = min(len(CASES), 2 * (os.cpu_count() or 2))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        out = {}
        for case, (script, args, _) in CASES.items():
            tmp = tmp_path_factory.mktemp(case)
            out[case] = (pool.submit(_run, script, args, tmp), tmp)
        yield out


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_gives_one_line(runs, case):
    future, tmp = runs[case]
    proc = future.result()
    script, _, message = CASES[case]
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and proc.stderr.endswith("\n"), proc.stderr
    assert lines[0].startswith("error: "), proc.stderr
    assert message in lines[0], proc.stderr
    assert not any(tmp.iterdir()), f"{script} wrote {sorted(tmp.iterdir())} on bad input"


def _tools() -> list[str]:
    """Every tool: tools/*.py and the folders of tools/ that run as a program (__main__.py)."""
    tools = ROOT / "tools"
    return sorted(
        [p.name for p in tools.glob("*.py")]
        + [p.name for p in tools.iterdir() if (p / "__main__.py").is_file()]
    )


def test_there_are_tools_and_every_case_names_one():
    assert len(_tools()) >= 10
    assert {script for script, _, _ in CASES.values()} <= set(_tools())


@pytest.fixture(scope="module")
def helps(tmp_path_factory):
    """tool -> future of its ``--help`` run."""
    workers = 2 * (os.cpu_count() or 2)
    tmp = tmp_path_factory.mktemp("help")
    with ThreadPoolExecutor(max_workers=workers) as pool:
        yield {tool: pool.submit(_run, tool, ["--help"], tmp) for tool in _tools()}


@pytest.mark.parametrize("tool", _tools())
def test_every_tool_has_help(helps, tool):
    proc = helps[tool].result()
    assert (proc.returncode, proc.stderr) == (0, ""), proc.stderr
    assert proc.stdout.startswith("usage: "), proc.stdout
    assert "-h, --help" in proc.stdout


def test_every_tool_is_listed_in_docs_tools_md():
    """docs/tools.md has a section per tool (``## tools/NAME``), and no section of a tool that is
    gone; the README links the page."""
    text = (ROOT / "docs" / "tools.md").read_text(encoding="utf-8")
    listed = re.findall(r"^## `tools/([\w.]+)`", text, flags=re.M)
    assert sorted(listed) == _tools()
    assert "(docs/tools.md)" in (ROOT / "README.md").read_text(encoding="utf-8")
