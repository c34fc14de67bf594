"""The package's one public API (positioning/__init__.py) and the old import paths of the names
that moved into its subpackages (positioning/deprecated.py)."""

from __future__ import annotations

import importlib
import subprocess
import sys
import warnings

import pytest

OLD_MODULES = (
    "api", "area", "bounded", "command", "dataset", "fingerprint", "fixes", "integrity", "irls",
    "lobe", "metrics", "nlos", "noise", "output", "resynth", "robust", "sanity", "tdoa", "track",
    "twin", "report", "cli",
)  # fmt: skip


def test_the_package_loads_its_estimators_on_first_use():
    """A command's start imports the harness (hallray.harness) and the error type: that must not
    load the estimators (and scipy.stats with them); the public names and the subpackages still
    resolve."""
    code = (
        "import sys\n"
        "import raytrace.cli.trace_scene, positioning.errors\n"
        "assert 'positioning.methods.registry' not in sys.modules\n"
        "assert 'scipy.stats' not in sys.modules\n"
        "import positioning\n"
        "from positioning import locate, Fixes, C0\n"
        "assert locate.__module__ == 'positioning.methods.run' and C0 == 299792458.0\n"
        "assert Fixes.__module__ == 'positioning.estimators.fixes'\n"
        "assert positioning.twin.__name__ == 'positioning.twin'\n"
        "assert set(positioning.__all__) <= set(dir(positioning))\n"
        "try:\n"
        "    positioning.no_such_thing\n"
        "except AttributeError as e:\n"
        "    assert 'no_such_thing' in str(e)\n"
        "else:\n"
        "    raise SystemExit('no AttributeError')\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "ok"


@pytest.mark.parametrize("old", OLD_MODULES)
def test_old_paths_warn_and_give_the_same_object(old):
    """Every name of a module that moved reads from its old path with a DeprecationWarning that
    names the new path, and is the very object of the new module."""
    module = importlib.import_module(f"positioning.{old}")
    assert module.MOVED, old
    for name, target in module.MOVED.items():
        new_module, _, new_name = target.partition(":")
        new = getattr(importlib.import_module(new_module), new_name or name)
        with pytest.warns(DeprecationWarning) as record:
            value = getattr(module, name)
        assert value is new, (old, name)
        (w,) = record
        assert str(w.message).startswith(f"positioning.{old}.{name} moved to {new_module}.")
        assert w.filename == __file__  # attributed to the caller, not to the shim
    assert sorted(dir(module)) == sorted(module.MOVED)


def test_old_from_import_still_works():
    with pytest.warns(DeprecationWarning, match=r"positioning\.tdoa\.Problem moved to "
                                                r"positioning\.model\.problem\.Problem"):  # fmt: skip
        from positioning.tdoa import Problem
    from positioning.model.problem import Problem as New

    assert Problem is New


def test_unknown_old_name_is_an_attribute_error():
    import positioning.tdoa

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # and no warning for a name that never existed
        with pytest.raises(AttributeError, match="no_such_name"):
            positioning.tdoa.no_such_name  # noqa: B018


def test_console_scripts_use_the_new_paths():
    """Every console script of pyproject.toml names a module that has its function, reached
    without a DeprecationWarning (an old path would print one at every command's start)."""
    tomllib = pytest.importorskip("tomllib")
    from pathlib import Path

    project = tomllib.loads((Path(__file__).parents[2] / "pyproject.toml").read_text())
    scripts = project["project"]["scripts"]
    assert {"estimate-positions", "accuracy-report"} <= set(scripts)
    for name, target in scripts.items():
        module, _, func = target.partition(":")
        with warnings.catch_warnings():
            warnings.simplefilter("error", DeprecationWarning)
            assert callable(getattr(importlib.import_module(module), func)), name
