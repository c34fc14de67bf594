"""Judging fixes: errors against the truth (:mod:`~positioning.evaluation.metrics`), the
integrity figures from the measurements alone (:mod:`~positioning.evaluation.integrity`) and
whether a run has a fix to trust (:mod:`~positioning.evaluation.trust`). Imports the model and the
estimators.
"""
