"""hallray's ray tracer: scenes with ITU-R P.2040 materials, paths by the image method, penetration
and UTD diffraction, channel and ToA emulation.

The main entry points::

    scene = raytrace.load_scene("hall")            # the bundled reference hall
    paths = raytrace.trace(scene, tx, rx, 3.775e9)  # all paths of all tx x rx links
"""

from __future__ import annotations

from .core.errors import HallrayError, MaterialError, SceneError, TraceInputError
from .core.version import __version__
from .scene.io import load_scene
from .scene.model import Scene
from .solver.config import TraceConfig
from .solver.context import TraceContext
from .solver.paths import Paths
from .solver.tracer import reevaluate, trace

__all__ = [
    "HallrayError",
    "MaterialError",
    "Paths",
    "Scene",
    "SceneError",
    "TraceConfig",
    "TraceContext",
    "TraceInputError",
    "__version__",
    "load_scene",
    "reevaluate",
    "trace",
]
