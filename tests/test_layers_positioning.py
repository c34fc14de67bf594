"""tools/check_layers.py's rules for positioning's layers and for hallray, on small synthetic
trees (one import per module) and on this checkout."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


class _Checker:
    """tools/check_layers.py's layer rule, run as a command (tools are not imported by path)."""

    @staticmethod
    def check(root: Path) -> list[str]:
        run = subprocess.run([sys.executable, str(ROOT / "tools" / "check_layers.py"), str(root),
                              "--rules", "layers"], capture_output=True, text=True)  # fmt: skip
        assert run.returncode in (0, 1), run.stderr
        lines = [x.removesuffix(" [layers]") for x in run.stdout.splitlines()]
        return [x for x in lines if x and not x.startswith(("ok:", "house rules violated"))]


@pytest.fixture(scope="module")
def layers():
    return _Checker


def _tree(root: Path, src: str, line: str) -> Path:
    """A checkout with the three packages, every module of the rules present, and ``src``
    holding one import line."""
    mods = [
        "hallray/__init__", "hallray/units", "hallray/harness", "hallray/main",
        "raytrace/__init__", "raytrace/core/__init__", "raytrace/core/scale",
        "raytrace/studies/__init__", "raytrace/studies/sweep", "raytrace/cli/__init__",
        "raytrace/cli/run",
        "positioning/__init__", "positioning/errors", "positioning/deprecated", "positioning/tdoa",
        "positioning/model/__init__", "positioning/model/problem",
        "positioning/io/__init__", "positioning/io/dataset",
        "positioning/estimators/__init__", "positioning/estimators/irls",
        "positioning/twin/__init__", "positioning/twin/estimator",
        "positioning/evaluation/__init__", "positioning/evaluation/metrics",
        "positioning/methods/__init__", "positioning/methods/run",
        "positioning/report/__init__", "positioning/cli/__init__",
    ]  # fmt: skip
    for m in mods:
        path = root / f"{m}.py"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(line + "\n" if m == src else "")
    return root


@pytest.mark.parametrize(
    "src, line, ok",
    [
        # positioning's layers, one way along ToA -> problem -> estimate -> evaluate -> report
        ("positioning/twin/estimator", "from ..estimators import irls", True),
        ("positioning/estimators/irls", "from ..twin import estimator", False),
        ("positioning/model/problem", "from ..io import dataset", False),
        ("positioning/io/dataset", "from ..model import problem", True),
        ("positioning/io/dataset", "from ..estimators import irls", False),
        ("positioning/evaluation/metrics", "from ..methods import run", False),
        ("positioning/methods/run", "from ..evaluation import metrics", True),
        ("positioning/model/problem", "from ..errors import PositioningError", True),
        ("positioning/methods/run", "import positioning", False),  # the API is for users
        ("positioning/methods/run", "from positioning.tdoa import C0", False),  # an old path
        ("positioning/tdoa", "from .deprecated import forward", True),  # a shim
        ("positioning/twin/__init__", "from ..deprecated import forward", True),
        ("positioning/twin/estimator", "from ..deprecated import forward", False),
        ("positioning/io/dataset", "import raytrace.core.scale", False),
        # raytrace and positioning
        ("raytrace/studies/sweep", "from positioning.io.dataset import load_dataset", True),
        ("raytrace/studies/sweep", "from positioning import locate", True),
        ("raytrace/studies/sweep", "from positioning.tdoa import C0", False),
        ("raytrace/core/scale", "import positioning.errors", False),
        # hallray, below both
        ("raytrace/core/scale", "from hallray.units import MAX_SCENE_M", True),
        ("positioning/model/problem", "from hallray.units import MAX_SCENE_M", True),
        ("hallray/harness", "import positioning.errors", False),
        ("hallray/units", "import raytrace.core.scale", False),
        ("hallray/main", "import raytrace.cli.run", True),  # the future console command
        ("raytrace/cli/run", "import hallray.main", False),  # which nothing imports
    ],
)  # fmt: skip
def test_one_import(layers, tmp_path, src, line, ok):
    problems = layers.check(_tree(tmp_path, src, line))
    assert (problems == []) == ok, problems
    assert all("against the layers" in p for p in problems), problems


def test_an_import_that_dodges_a_cycle_is_found(layers, tmp_path):
    root = _tree(tmp_path, "positioning/io/dataset", "from ..model import problem")
    (root / "positioning/model/problem.py").write_text(
        "def f():\n    from ..model import area\n"
    )
    (root / "positioning/model/area.py").write_text("from . import problem\n")
    problems = layers.check(root)
    assert len(problems) == 2 and "import cycle" in problems[0] and "dodges" in problems[1]


def test_this_checkout_follows_the_layers(layers):
    assert layers.check(ROOT) == []
