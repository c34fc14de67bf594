"""The installed distribution holds every package of the checkout (pyproject lists them by name:
a new subpackage left out of the list is missing from a plain ``pip install .``)."""

from __future__ import annotations

from pathlib import Path

import tomllib

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_of_the_checkout_is_listed_in_pyproject():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    listed = set(cfg["tool"]["setuptools"]["packages"])
    found = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for top in ("raytrace", "positioning", "hallray")
        for p in (ROOT / top).rglob("__init__.py")
    }
    assert found - listed == set(), "add these to [tool.setuptools] packages in pyproject.toml"
    # the bundled scenes are mapped from scenes/ (package-dir), not found under raytrace/
    assert listed - found == {"raytrace._scenes", "raytrace._scenes.canonical"}
