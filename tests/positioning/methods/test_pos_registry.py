"""The registry of methods (positioning.methods.registry): each method's parameters are its
config's fields with the config's defaults, and running it gives the estimator's Fixes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from pos_synth import PAPER_BS, synth_map

from positioning import METHODS, Fixes, make_problem, method_names, resolve_params, run_method
from positioning.estimators.irls import IrlsConfig, irls
from positioning.model.tdoa import C0
from positioning.twin.estimator import TwinConfig

#: The parameter the registry names differently from its config field.
RENAMED = {"map": "fingerprint_map"}


def test_parameters_are_the_config_fields_with_their_defaults():
    configs = {
        "ls": "LsConfig", "irls": "IrlsConfig", "m-estimator": "MEstimatorConfig",
        "subset": "SubsetConfig", "nlos-aware": "NlosAwareConfig", "nlos-map": "NlosMapConfig",
        "twin": "TwinConfig",
    }  # fmt: skip
    import positioning.estimators.irls as e1
    import positioning.estimators.nlos as e2
    import positioning.estimators.robust as e3
    import positioning.twin.estimator as e4

    for name, cls_name in configs.items():
        cls = next(getattr(m, cls_name) for m in (e1, e2, e3, e4) if hasattr(m, cls_name))
        fields = {f.name: f for f in dataclasses.fields(cls)}
        for param, (default, _) in METHODS[name].params.items():
            if param == "fallback":  # a method name the registry binds, not a config field
                continue
            field = fields[RENAMED.get(param, param)]
            if field.default is not dataclasses.MISSING:
                assert default == field.default, (name, param)


def test_run_gives_the_estimators_fixes():
    rng = np.random.default_rng(5)
    dev = np.column_stack([rng.uniform(3, 26, 4), rng.uniform(3, 22, 4), np.ones(4)])
    toa = np.linalg.norm(dev[:, None] - PAPER_BS[None], axis=2) / C0 + rng.normal(0, 1e-10, (4, 4))
    prob = make_problem(toa, PAPER_BS, height_m=1.0)
    p = resolve_params("irls", {"u_max": "2.5"}, prob.n_bs)
    f = METHODS["irls"].run(prob, p)
    g = irls(prob, IrlsConfig(u_max=2.5))
    assert isinstance(f, Fixes)
    np.testing.assert_array_equal(f.xyz, g.xyz)
    h = run_method(prob, "irls", u_max=2.5)
    np.testing.assert_array_equal(h.xyz, g.xyz)  # no service area: nothing moved
    assert h.params == p and h.method == "irls" and "estimates" in h.extra
    t = run_method(prob, "twin", map=synth_map(), bias="cell", fallback="ls")
    assert t.method == "twin" and t.params["map"] is not None and t.params["fallback"] == "ls"
    assert set(method_names(include_map=False)) == set(METHODS) - {"twin"}


def test_method_func_is_deprecated_but_works():
    prob = make_problem(np.zeros((1, 4)), PAPER_BS, height_m=1.0)
    with pytest.warns(DeprecationWarning, match=r"positioning\.Method\.func moved to "):
        func = METHODS["ls"].func
    np.testing.assert_array_equal(func(prob, reference=None, tol_m=1e-9, max_iter=50).xyz,
                                  METHODS["ls"].run(prob, resolve_params("ls", {})).xyz)  # fmt: skip


def test_twin_config_takes_the_map_under_its_own_name():
    assert "map" not in {f.name for f in dataclasses.fields(TwinConfig)}
    assert "map" in METHODS["twin"].params  # the command line's name for it stays
