"""Old import paths of names that moved (issue 35): they keep working for one release.

A module whose names moved keeps a module-level ``__getattr__`` made by :func:`forward`: reading
an old name (``from positioning.tdoa import Problem``) imports its new module, warns with a
:class:`DeprecationWarning` that names the new path, and returns the same object. Code of this
project uses the new paths (the test run turns these warnings into errors, see ``pyproject.toml``).
Standard library only.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from importlib import import_module
from typing import Any

#: How the warnings begin (``pyproject.toml`` matches it to make them errors in the tests).
MESSAGE = "{old} moved to {new}; the old path goes away in the next release"


def forward(
    module: str, moved: Mapping[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """Module-level ``__getattr__`` and ``__dir__`` of an old module whose names moved.

    Parameters
    ----------
    module : the old module's name (``__name__``)
    moved : old name -> its new module (``"positioning.model.problem"``), or ``"module:name"``
        where the name changed as well

    Returns
    -------
    ``(__getattr__, __dir__)`` to assign at the old module's top level.
    """

    def __getattr__(name: str) -> Any:
        target = moved.get(name)
        if target is None:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        new_module, _, new_name = target.partition(":")
        new_name = new_name or name
        warnings.warn(
            MESSAGE.format(old=f"{module}.{name}", new=f"{new_module}.{new_name}"),
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(import_module(new_module), new_name)

    def __dir__() -> list[str]:
        return sorted(moved)

    return __getattr__, __dir__
