"""Compiled loops of the tracer (numba, options in :mod:`raytrace.core.jit`), one module per stage.

* **Pruning** (:mod:`.prune`: :func:`facet_wedge_pairs`, :func:`expand_over_others`,
  :func:`second_order_candidates`, :func:`surely_inside`): exact necessary conditions, cheapest
  first, in place of numpy's dense candidate matrices; :data:`PRUNE` switches them off.
* **Mixed candidates** (:mod:`.mixed`: :func:`reflection_edge_points`,
  :func:`mixed_candidates`): the RD and DR pairs pruned, then tested exactly one at a time with
  the physics and scene modules' compiled scalar rules.
* **Lines against solids and sheets, points against triangles** (:mod:`.solids`:
  :func:`line_span`, :func:`touch_rows`, :func:`edge_distance`, :func:`shadowed_groups`,
  :func:`shadowed_triples`): the shared scalar tests of the walk and the opaque test, and the
  shadows of opaque solids.
* **Segment walk and its probes** (:mod:`.walk`: :func:`walk_rays`, :func:`walk_hits`,
  :func:`walk_record`, :func:`unseen_entries`, :func:`entry_points`, :func:`end_probes`): what a
  segment crosses (:mod:`raytrace.solver.penetration`).
* **Opaque test** (:mod:`.opaque`: :func:`segment_rays`, :func:`opaque_blocks`): the rays of one
  segment of every candidate, and which first opaque hits block.
* **Fields** (:mod:`.fields`: :func:`path_gains`): the field vector carried along each path, with
  the ITU-R P.2040 coefficients computed on the way and the diffraction operators computed
  beforehand.
* **Interaction sequences** (:mod:`.sequences`: :func:`interaction_sequences`).
* **Moving boxes** (:mod:`.boxes`: :func:`paths_meeting_boxes`): the paths a snapshot's
  forklifts affect (:mod:`raytrace.solver.incremental`).

The kernels are re-exported here, so that the stages call them as ``kernels.<name>``.

The pruning and walk kernels write the numpy expressions they replaced in numpy's order, so the
traced paths' geometry and penetrations are bitwise those of the numpy form on the machine they
were checked on (``tools/trace_identity.py``); :func:`path_gains` differs in the last bits of
the gains only (:mod:`.fields`).
"""

from __future__ import annotations

from .boxes import paths_meeting_boxes
from .fields import path_gains
from .mixed import mixed_candidates, reflection_edge_points
from .opaque import opaque_blocks, segment_rays
from .prune import (
    along_and_off_rows,
    expand_over_others,
    facet_wedge_pairs,
    second_order_candidates,
    surely_inside,
)
from .reach import (
    EdgeLeaves,
    edge_leaves,
    facet_wedge_pairs_near,
    facet_wedge_pairs_tree,
    first_order_candidates,
    second_facets,
    second_pairs_reaching,
)
from .sequences import interaction_sequences
from .solids import edge_distance, line_span, shadowed_groups, shadowed_triples, touch_rows
from .walk import end_probes, entry_points, unseen_entries, walk_hits, walk_rays, walk_record

__all__ = ["PRUNE", "EXHAUSTIVE", "TREES", "TABLE_MAX_PAIRS", "use_tables", "surely_inside", "facet_wedge_pairs", "EdgeLeaves", "edge_leaves", "facet_wedge_pairs_near", "facet_wedge_pairs_tree", "first_order_candidates", "second_facets", "second_pairs_reaching", "expand_over_others",
           "reflection_edge_points", "along_and_off_rows", "second_order_candidates", "line_span",
           "shadowed_groups", "shadowed_triples", "edge_distance",
           "opaque_blocks", "touch_rows", "entry_points", "end_probes",
           "walk_record", "unseen_entries", "walk_rays", "walk_hits", "segment_rays",
           "path_gains", "interaction_sequences", "mixed_candidates", "paths_meeting_boxes"]

#: The callers pass this as the kernels' ``prune``: False switches their pruning tests off (they
#: then return every candidate that satisfies the rules, with unbounded spans), so that a trace
#: with it set shows that the pruning loses no path (the tests do; it is far slower).
PRUNE = True

#: True: the stages enumerate their candidates by scanning every element as before the scene's
#: trees (every facet pair's table for double reflections, every object's edges for the mixed
#: stages): the exhaustive path, kept as the tests' oracle. False (the default): the scans on
#: small scenes (:func:`use_tables`), the queries on the trees (:mod:`raytrace.scene.spatial`)
#: on larger ones, with the same exact tests after either, so the paths are the same.
EXHAUSTIVE = False
#: True: the trees on every scene, however small (the tests compare them with the scans).
TREES = False
#: Scenes whose (facets x max(facets, wedges)) is at most this scan their elements: on the hall
#: (616 facets, 774 wedges) the scans are 25-40 % faster than the trees' walks, and their tables
#: stay under 2^21 entries (a few MB) whatever the scene; larger scenes use the trees.
TABLE_MAX_PAIRS = 1 << 21


def use_tables(n_facets: int, n_wedges: int) -> bool:
    """Whether a trace of a scene with these counts scans its elements (:data:`EXHAUSTIVE`,
    :data:`TREES`, :data:`TABLE_MAX_PAIRS`) instead of querying the trees."""
    if EXHAUSTIVE:
        return True
    if TREES:
        return False
    return n_facets * max(n_facets, n_wedges) <= TABLE_MAX_PAIRS
