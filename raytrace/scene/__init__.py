"""The scene layer: triangles, objects and materials, facets and wedges, Embree queries, moving
objects, and the scene's deployment metadata (:mod:`raytrace.scene.model`, :mod:`.construction`,
:mod:`.queries`, :mod:`.caches`, :mod:`.io`, :mod:`.elements`, :mod:`.accel`, :mod:`.dynamic`,
:mod:`.motion`, :mod:`.metadata`)."""

from .elements import Facets, SceneObject, Wedges
from .io import load_scene
from .metadata import SceneMetadata
from .model import Scene

__all__ = ["Facets", "Scene", "SceneMetadata", "SceneObject", "Wedges", "load_scene"]
