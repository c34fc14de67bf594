"""The measurement model, the first floor of positioning: from ToAs to a problem.

The TDoA equations (:mod:`~positioning.model.tdoa`, paper eqs. 4-6), the validated input of every
estimator (:mod:`~positioning.model.problem`: ``Problem``, ``LinkInfo``), its residual functions
(:mod:`~positioning.model.residuals`, eq. 7 and the pseudo-range model), the service area
(:mod:`~positioning.model.area`) and the per-measurement error model of a band-limited ToA
(:mod:`~positioning.model.noise`). Imports nothing of positioning but its error type.
"""
