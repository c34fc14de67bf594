"""The estimators: from a problem to fixes.

Every estimator takes a :class:`~positioning.model.problem.Problem` and a small frozen config and
returns :class:`~positioning.estimators.fixes.Fixes`. The batched least-squares machinery
(:mod:`~positioning.estimators.solver`), the paper's LS and IRLS
(:mod:`~positioning.estimators.irls`), the robust ones (:mod:`~positioning.estimators.robust`:
``m-estimator``, ``subset``, ``nlos-aware``), the physics mixture
(:mod:`~positioning.estimators.nlos`: ``nlos-map``), the re-solve inside the service area
(:mod:`~positioning.estimators.bounded`) and the tracking filter over epochs
(:mod:`~positioning.estimators.track`). Imports only the model.
"""
