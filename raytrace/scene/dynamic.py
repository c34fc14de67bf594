"""Fast scenes for moving objects: a static scene followed by a few rigidly posed objects.

``Scene.from_meshes`` processes every object with trimesh (merging, orientation, facets, wedges)
and costs about 0.5 s for the reference hall. A snapshot with moving forklifts changes only a
few boxes, so the static part is processed once and reused:

* :func:`extend_scene` joins an existing scene and a scene of extra objects into one scene whose
  arrays are exactly those ``Scene.from_meshes(static_meshes + extra_meshes)`` would build: the
  static objects keep their object, face, facet and wedge indices, the extra objects follow.
  Only the Embree intersector is rebuilt (a few milliseconds).
* :func:`posed` moves every object of a small template scene (e.g. one box per forklift, built
  once at the origin) by its own rigid motion, transforming vertices, normals, facet planes and
  wedges directly (no trimesh processing). The result is a valid scene of the moved objects:
  rigid motions keep the facets, the wedges and the orientation of closed solids.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.errors import SceneError
from .accel import facet_tree, wedge_tree
from .caches import convex_flags, embree_meshes
from .elements import Facets, SceneObject, Wedges
from .model import Scene


def extend_scene(base: Scene, extra: Scene) -> Scene:
    """The objects of ``base`` followed by those of ``extra``, as one scene.

    Equivalent to ``Scene.from_meshes(base_meshes + extra_meshes, base.materials)`` when both were
    built by ``Scene.from_meshes`` from those meshes (same arrays, same indices), without
    reprocessing any mesh, as long as no object of one part touches an object of the other: the
    loader's removal of edges buried in another solid is applied within each part only (a
    forklift never touches the static objects of a valid hall).

    Parameters
    ----------
    base : Scene
        The static scene; its metadata, material library and source are kept.
    extra : Scene
        The added objects (e.g. from :func:`posed`). Their materials must be in
        ``base.materials``.

    Returns
    -------
    Scene, with a fresh Embree intersector over all objects (geometry id = object index).
    """
    missing = [m for m in extra.material_names if m not in base.materials]
    if missing:
        raise SceneError(f"material {missing[0]!r} of an added object is not in the scene library")
    names = list(base.material_names) + [
        m for m in extra.material_names if m not in base.material_names
    ]
    # material index of the extra scene -> index in the joined list
    remap = np.array([names.index(m) for m in extra.material_names], dtype=np.int64)
    n_obj, n_v, n_f = len(base.objects), len(base.vertices), len(base.faces)
    objects = list(base.objects) + [
        SceneObject(o.name, o.material, o.closed, o.face_start + n_f, o.face_count)
        for o in extra.objects
    ]
    bf, ef = base.facets, extra.facets
    facets = Facets(
        normal=np.concatenate([bf.normal, ef.normal]),
        offset=np.concatenate([bf.offset, ef.offset]),
        object=np.concatenate([bf.object, ef.object + n_obj]),
        material=np.concatenate([bf.material, remap[ef.material]]),
        two_sided=np.concatenate([bf.two_sided, ef.two_sided]),
        area=np.concatenate([bf.area, ef.area]),
        tri_start=np.concatenate([bf.tri_start, ef.tri_start + len(bf.triangles)]),
        tri_count=np.concatenate([bf.tri_count, ef.tri_count]),
        triangles=np.concatenate([bf.triangles, ef.triangles]),
    )
    bw, ew = base.wedges, extra.wedges

    def joined_wedge_field(name: str) -> np.ndarray:
        tail = getattr(ew, name)
        if name == "object":
            tail = tail + n_obj
        elif name == "material":
            tail = remap[tail]
        return np.concatenate([getattr(bw, name), tail])

    wedges = Wedges(**{name: joined_wedge_field(name) for name in bw.arrays()})
    scene = dataclasses.replace(
        base,
        vertices=np.concatenate([base.vertices, extra.vertices]),
        faces=np.concatenate([base.faces, extra.faces + n_v]),
        face_object=np.concatenate([base.face_object, extra.face_object + n_obj]),
        face_normal=np.concatenate([base.face_normal, extra.face_normal]),
        objects=objects,
        material_names=names,
        facets=facets,
        wedges=wedges,
        n_degenerate_dropped=base.n_degenerate_dropped + extra.n_degenerate_dropped,
    )
    if hasattr(base, "n_buried_wedges"):
        scene.n_buried_wedges = base.n_buried_wedges + getattr(extra, "n_buried_wedges", 0)
    # the facets' trees: the static scene's (built once, kept on its facets) and one over the
    # moving objects' few facets, so that a snapshot never builds a tree of the whole scene
    facets.cache["forest"] = tuple((facet_tree(x), first)
                                   for x, first in ((bf, 0), (ef, len(bf))) if len(x))  # fmt: skip
    wedges.cache["forest"] = tuple((wedge_tree(x), first)
                                   for x, first in ((bw, 0), (ew, len(bw))) if len(x))  # fmt: skip
    # the (facets x facets) table of double reflections, if a small scene's trace asks for it:
    # only the moving objects' rows and columns are new (the whole table was 75 of a hall
    # snapshot's 250 ms of CPU)
    facets.cache["extends"] = bf
    # the static objects' triangles as Embree takes them are the base's: their cut depends on
    # the scene's extent only, which objects inside the hall leave as it is (16 of a hall
    # snapshot's 21 ms went into cutting all 115 objects again)
    if scene.extent == base.extent and np.array_equal(scene.embree_origin(), base.embree_origin()):
        origin = scene.embree_origin()
        local = scene.vertices - origin if origin.any() else scene.vertices
        scene.caches.embree_meshes = list(base.embree_meshes()) + embree_meshes(
            local, scene.faces, objects[n_obj:], scene.extent
        )
        # so does which closed solids are convex (its tolerance is the extent's)
        added = scene.object_closed.copy()
        added[:n_obj] = False
        convex = convex_flags(scene.vertices, scene.faces, objects, facets, added, scene.extent)
        convex[:n_obj] = base.convex_objects()
        scene.caches.convex = convex
        scene.caches.extends = base
    scene.build_embree()
    return scene


def posed(template: Scene, rotation: np.ndarray, translation: np.ndarray) -> Scene:
    """The template's objects, each moved by its own rigid motion ``x -> R x + t``.

    Parameters
    ----------
    template : Scene
        O objects (e.g. one box per forklift, centred at the origin).
    rotation : (O, 3, 3) float
        Proper rotation matrices (det +1), one per object.
    translation : (O, 3) float, metres

    Returns
    -------
    Scene without an Embree intersector (meant for :func:`extend_scene`), same objects, facets
    and wedges in the same order as the template.
    """
    rot = np.asarray(rotation, dtype=float).reshape(-1, 3, 3)
    tr = np.asarray(translation, dtype=float).reshape(-1, 3)
    n_obj = len(template.objects)
    if rot.shape[0] != n_obj or tr.shape[0] != n_obj:
        raise SceneError(
            f"posed: {n_obj} objects but {rot.shape[0]} rotations, {tr.shape[0]} shifts"
        )

    def move(points: np.ndarray, obj: np.ndarray) -> np.ndarray:
        return np.einsum("nij,nj->ni", rot[obj], points) + tr[obj]

    def turn(vectors: np.ndarray, obj: np.ndarray) -> np.ndarray:
        return np.einsum("nij,nj->ni", rot[obj], vectors)

    # vertex owner: faces are grouped by object and from_meshes does not share vertices between
    # objects
    v_obj = np.zeros(len(template.vertices), dtype=np.int64)
    v_obj[template.faces.reshape(-1)] = np.repeat(template.face_object, 3)
    fc, w = template.facets, template.wedges
    normal = turn(fc.normal, fc.object)
    t_obj = np.repeat(fc.object, fc.tri_count)
    tris = move(fc.triangles.reshape(-1, 3), np.repeat(t_obj, 3)).reshape(-1, 3, 3)
    facets = dataclasses.replace(
        fc,
        normal=normal,
        # n' . (R x + t) = n . x + n' . t
        offset=fc.offset + np.einsum("ij,ij->i", normal, tr[fc.object]),
        triangles=tris,
    )
    wedges = dataclasses.replace(
        w,
        start=move(w.start, w.object),
        end=move(w.end, w.object),
        direction=turn(w.direction, w.object),
        normal0=turn(w.normal0, w.object),
        normal1=turn(w.normal1, w.object),
        face0_dir=turn(w.face0_dir, w.object),
    )
    return dataclasses.replace(
        template,
        vertices=move(template.vertices, v_obj),
        face_normal=turn(template.face_normal, template.face_object),
        facets=facets,
        wedges=wedges,
    )


def yaw_rotations(yaw_rad: np.ndarray) -> np.ndarray:
    """Rotations about +z by ``yaw_rad`` (O,) radians, (O, 3, 3); exact at multiples of 90 deg
    (so that axis-aligned boxes stay exactly axis-aligned)."""
    yaw = np.asarray(yaw_rad, dtype=float).reshape(-1)
    c, s = np.cos(yaw), np.sin(yaw)
    quarter = yaw / (0.5 * np.pi)
    exact = np.abs(quarter - np.round(quarter)) < 1e-12
    q = np.mod(np.round(quarter).astype(np.int64), 4)
    c = np.where(exact, np.array([1.0, 0.0, -1.0, 0.0])[q], c)
    s = np.where(exact, np.array([0.0, 1.0, 0.0, -1.0])[q], s)
    out = np.zeros((len(yaw), 3, 3))
    out[:, 0, 0], out[:, 0, 1] = c, -s
    out[:, 1, 0], out[:, 1, 1] = s, c
    out[:, 2, 2] = 1.0
    return out
