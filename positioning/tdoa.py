"""Deprecated: ``positioning.tdoa`` moved to :mod:`positioning.estimators.solver`,
:mod:`positioning.model.problem`, :mod:`positioning.model.residuals`,
:mod:`positioning.model.tdoa`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "COND_LIMIT": "positioning.estimators.solver",
    "Solution": "positioning.estimators.solver",
    "first_valid": "positioning.estimators.solver",
    "ill_conditioned": "positioning.estimators.solver",
    "levenberg_marquardt": "positioning.estimators.solver",
    "linear_start": "positioning.estimators.solver",
    "pseudorange_start": "positioning.estimators.solver",
    "solve_pseudorange": "positioning.estimators.solver",
    "solve_tdoa": "positioning.estimators.solver",
    "DUPLICATE_TOL_M": "positioning.model.problem",
    "LinkInfo": "positioning.model.problem",
    "Problem": "positioning.model.problem",
    "make_problem": "positioning.model.problem",
    "ModelFun": "positioning.model.residuals",
    "pseudorange_model": "positioning.model.residuals",
    "pseudorange_residuals": "positioning.model.residuals",
    "tdoa_model": "positioning.model.residuals",
    "C0": "positioning.model.tdoa",
    "pseudoranges": "positioning.model.tdoa",
    "range_differences": "positioning.model.tdoa",
    "ranges_and_units": "positioning.model.tdoa",
    "signed_tdoa": "positioning.model.tdoa",
}

__getattr__, __dir__ = forward(__name__, MOVED)
