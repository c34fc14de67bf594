"""tools/check_layers.py: every rule group fires on a small synthetic checkout that breaks it, and
stays quiet on one that only comes close (the limits exactly, the allowed exceptions).

The tool runs as a maintainer and CI run it (``python tools/check_layers.py ROOT``), once per
tree and rule selection; the expected lines are exact (``path:line: what [rule]``).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
RULES = ("layers", "size", "private", "builtins", "syspath")


def _write(root: Path, files: dict[str, str]) -> Path:
    """A checkout holding ``files`` and the three packages (the checker needs them)."""
    for rel, text in {"hallray/__init__.py": "", **files}.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    return root


def _body(n_lines: int) -> str:
    """A function of exactly ``n_lines`` lines, ``def`` line included."""
    return "def work():\n" + "    x = 1\n" * (n_lines - 2) + "    return x\n"


def _module(n_lines: int) -> str:
    """A module of exactly ``n_lines`` lines."""
    return "".join(f"X{k} = {k}\n" for k in range(n_lines))


#: Files every synthetic checkout has (two packages, as the tool requires).
BASE = {
    "raytrace/__init__.py": '"""pkg"""\n__version__ = "0"\n',
    "raytrace/core/__init__.py": "",
    "raytrace/core/b.py": '__all__ = ["shown"]\n_hidden = 1\nshown = 2\n',
    "raytrace/core/_impl.py": "thing = 1\n",
    "positioning/__init__.py": "",
}

#: Comes close to every rule without breaking one.
CLEAN = {
    **BASE,
    # size: the limits exactly, and a long kernel that says why
    "raytrace/core/sized.py": _module(800),
    "raytrace/core/funcs.py": _body(100)
    + "def kernel():\n"
    + '    """Walk the rays.\n\n    long kernel: one compiled loop; split, it would copy arrays."""\n'
    + "    x = 1\n" * 150,
    # private: dunders, its own private names, a private module from inside its package, names
    # of other libraries
    "raytrace/core/user.py": (
        "from .b import __all__\n"
        "from . import _impl\n"
        "from ._impl import thing\n"
        "from .b import shown\n"
        "from os import _exit\n"
        "_mine = 1\n"
        "class A:\n"
        "    def __init__(self):\n"
        "        self._x = _mine + _impl.thing + thing + shown\n"
    ),
    # builtins: private and nested functions, private classes, locals, the allowed banners
    "raytrace/core/names.py": (
        'license = "MIT"\n'
        "def _f(map, id):\n"
        "    max = 3\n"
        "    def inner(type):\n"
        "        return type\n"
        "    return max\n"
        "class _Hidden:\n"
        "    def method(self, input):\n"
        "        return input\n"
        "def shown(map_, *, kind=None, **options):\n"
        "    return [x for x in map_]\n"
    ),
    # syspath: reading sys.path and sys.argv is fine, and the packages are not checked
    "tools/tool.py": "import sys\nprint(sys.path, sys.argv)\n",
    "tests/test_a.py": "import sys\n\ndef test_a():\n    assert sys.path\n",
    "raytrace/core/finder.py": "import sys\nsys.path.insert(0, 'x')\n",
    # tests may reach into the private helpers they test
    "tests/test_b.py": "from raytrace.core.b import _hidden\n\ndef test_b():\n    assert _hidden\n",
}

#: Breaks each rule; rule -> the exact lines it prints.
DIRTY_FILES = {
    **BASE,
    "positioning/uses_raytrace.py": "import raytrace.core.b\n",
    "raytrace/core/big.py": _module(801),
    "tools/slow.py": "\n" + _body(101),
    "raytrace/core/thief.py": (
        "from .b import _hidden\n"
        "from raytrace.core import b\n"
        "import raytrace.core.b as bb\n"
        "import raytrace.core\n"
        "y = b._hidden + bb._hidden + raytrace.core.b._hidden\n"
    ),
    "raytrace/physics/outsider.py": "from raytrace.core._impl import thing\nimport raytrace.core._impl\n",
    "tools/steal.py": "from raytrace.core.b import _hidden\n",
    "raytrace/core/shadows.py": (
        "format = 1\n"
        "from os import open\n"
        "def map(x):\n"
        "    return x\n"
        "class Table:\n"
        "    def rows(self, id, *, type=None, **vars):\n"
        "        return id\n"
        "def load(path, *input):\n"
        "    return path\n"
    ),
    "tests/test_path.py": (
        "import sys\n"
        "import importlib.util\n"
        "import runpy\n"
        "sys.path.insert(0, 'x')\n"
        "sys.path.append('y')\n"
        "sys.path = ['z']\n"
        "sys.path += ['w']\n"
        "spec = importlib.util.spec_from_file_location('m', 'm.py')\n"
        "runpy.run_path('m.py')\n"
    ),
    "tools/path_tool.py": "from sys import path\n",
}
DIRTY = {
    "layers": [
        "positioning/uses_raytrace.py:1: positioning.uses_raytrace imports raytrace.core.b "
        "(against the layers) [layers]",
    ],
    "size": [
        "raytrace/core/big.py:1: module has 801 lines (over 800) [size]",
        "tools/slow.py:2: function work has 101 lines (over 100; a numba kernel may say "
        "'long kernel:' why) [size]",
    ],
    "private": [
        "raytrace/core/thief.py:1: imports private name _hidden from raytrace.core.b [private]",
        "raytrace/core/thief.py:5: uses private name _hidden of raytrace.core.b [private]",
        "raytrace/core/thief.py:5: uses private name _hidden of raytrace.core.b [private]",
        "raytrace/core/thief.py:5: uses private name _hidden of raytrace.core.b [private]",
        "raytrace/physics/outsider.py:1: imports raytrace.core._impl, private to raytrace.core "
        "[private]",
        "raytrace/physics/outsider.py:2: imports raytrace.core._impl, private to raytrace.core "
        "[private]",
        "tools/steal.py:1: imports private name _hidden from raytrace.core.b [private]",
    ],
    "builtins": [
        "raytrace/core/shadows.py:1: module-level name format shadows the builtin [builtins]",
        "raytrace/core/shadows.py:2: module-level name open shadows the builtin [builtins]",
        "raytrace/core/shadows.py:3: module-level name map shadows the builtin [builtins]",
        "raytrace/core/shadows.py:6: parameter id of Table.rows shadows the builtin [builtins]",
        "raytrace/core/shadows.py:6: parameter type of Table.rows shadows the builtin [builtins]",
        "raytrace/core/shadows.py:6: parameter vars of Table.rows shadows the builtin [builtins]",
        "raytrace/core/shadows.py:8: parameter input of load shadows the builtin [builtins]",
    ],
    "syspath": [
        "tools/path_tool.py:1: imports sys.path by name [syspath]",
        "tests/test_path.py:4: calls sys.path.insert [syspath]",
        "tests/test_path.py:5: calls sys.path.append [syspath]",
        "tests/test_path.py:6: assigns to sys.path [syspath]",
        "tests/test_path.py:7: assigns to sys.path [syspath]",
        "tests/test_path.py:8: loads a module by its file location "
        "(importlib.util.spec_from_file_location) [syspath]",
        "tests/test_path.py:9: loads a module by its file location (runpy.run_path) [syspath]",
    ],
}


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(ROOT / "tools" / "check_layers.py"), *args],
        capture_output=True,
        text=True,
        timeout=120,
        stdin=subprocess.DEVNULL,
    )


@pytest.fixture(scope="module")
def dirty(tmp_path_factory) -> subprocess.CompletedProcess:
    return _run(str(_write(tmp_path_factory.mktemp("dirty"), DIRTY_FILES)))


def test_clean_tree_passes_every_rule(tmp_path):
    proc = _run(str(_write(tmp_path, CLEAN)))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout == f"ok: {', '.join(RULES)}\n"
    assert proc.stderr == ""


@pytest.mark.parametrize("rule", RULES)
def test_each_rule_fires_on_its_violations(dirty, rule):
    assert dirty.returncode == 1, dirty.stderr
    lines = [ln for ln in dirty.stdout.splitlines() if ln.endswith(f"[{rule}]")]
    assert sorted(lines) == sorted(DIRTY[rule])


def test_every_line_names_a_rule_and_the_summary_names_the_broken_ones(dirty):
    expected = sorted(line for lines in DIRTY.values() for line in lines)
    assert sorted(dirty.stdout.splitlines()) == expected
    assert dirty.stderr == f"house rules violated: {', '.join(RULES)}\n"


def test_rules_option_runs_only_the_chosen_groups(tmp_path):
    proc = _run(str(_write(tmp_path, DIRTY_FILES)), "--rules", "size,builtins")
    assert proc.returncode == 1
    assert sorted(proc.stdout.splitlines()) == sorted(DIRTY["size"] + DIRTY["builtins"])
    assert proc.stderr == "house rules violated: size, builtins\n"
    proc = _run(str(tmp_path), "--rules", "layers")
    assert proc.returncode == 1 and proc.stdout.splitlines() == DIRTY["layers"]


def test_unknown_rule_is_one_line_and_exit_2(tmp_path):
    proc = _run(str(_write(tmp_path, CLEAN)), "--rules", "size,nosuch")
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr == (
        f"error: argument --rules: unknown rule group 'nosuch' (known: {', '.join(RULES)})\n"
    )


def test_a_file_that_is_not_python_is_one_line_and_exit_2(tmp_path):
    _write(tmp_path, {**CLEAN, "tools/broken.py": "def (:\n"})
    proc = _run(str(tmp_path), "--rules", "size")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert len(proc.stderr.splitlines()) == 1
    assert proc.stderr.startswith(f"error: {tmp_path / 'tools' / 'broken.py'}: not valid Python")
