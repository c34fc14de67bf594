"""raytrace.core.jit: the kernels' options, and compiling without a writable cache."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from raytrace.core import jit


def test_kernel_divides_by_zero_as_numpy_and_adds_without_fusing():
    @jit.kernel("f8[::1](f8[::1], f8[::1], f8[::1])")
    def f(a, b, c):
        out = np.empty(len(a))
        for i in range(len(a)):
            out[i] = a[i] * b[i] + c[i] if c[i] != 0.0 else a[i] / c[i]
        return out

    a = np.array([0.1, 1.0, -1.0, 0.0, 1.0 + 2**-30])
    b = np.array([0.3, 2.0, 3.0, 0.0, 1.0 - 2**-30])
    c = np.array([0.7, 0.0, 0.0, 0.0, -1.0])
    with np.errstate(divide="ignore", invalid="ignore"):
        expect = np.where(c != 0.0, a * b + c, a / c)
    # numpy's bits: inf and nan for x / 0 (no exception), and a * b + c rounded twice (a fused
    # multiply-add would give 2**-60 + ... for the last row, not 0 - 2**-60)
    np.testing.assert_array_equal(f(a, b, c), expect)


def test_kernel_without_a_cache_location_compiles_in_memory(monkeypatch):
    real = numba.njit

    def no_locator(*args, **kwargs):
        if kwargs.get("cache"):
            def fail(fn):
                raise RuntimeError(f"cannot cache function {fn.__name__!r}: no locator available "
                                   "for file 'x.py'")  # fmt: skip
            return fail
        return real(*args, **kwargs)

    monkeypatch.setattr(numba, "njit", no_locator)

    @jit.inline
    def half(x):
        return 0.5 * x

    @jit.kernel("f8(f8)")
    def twice(x):
        return 4.0 * half(x)

    assert twice(1.5) == 3.0


def test_other_compile_errors_are_not_hidden(monkeypatch):
    def broken(*args, **kwargs):
        def fail(fn):
            raise RuntimeError("something else")
        return fail

    monkeypatch.setattr(numba, "njit", broken)
    with pytest.raises(RuntimeError, match="something else"):
        jit.kernel("f8(f8)")(lambda x: x)


#: The modules of the compiled kernels (the packages split by stage and by part included).
KERNEL_MODULES = (
    "raytrace.scene.accel",
    "raytrace.physics.materials.coefficients",
    "raytrace.physics.utd.keller",
    "raytrace.physics.utd.frames",
    "raytrace.physics.utd.coefficients",
    "raytrace.physics.utd.operators",
    "raytrace.solver.kernels.prune",
    "raytrace.solver.kernels.mixed",
    "raytrace.solver.kernels.solids",
    "raytrace.solver.kernels.walk",
    "raytrace.solver.kernels.opaque",
    "raytrace.solver.kernels.fields",
    "raytrace.solver.kernels.sequences",
)


def _dispatchers(module_name):
    import importlib

    from numba.core.registry import CPUDispatcher

    mod = importlib.import_module(module_name)
    return {name: obj for name, obj in vars(mod).items()
            if isinstance(obj, CPUDispatcher) and obj.__module__ == module_name}  # fmt: skip


def test_every_kernel_is_compiled_with_the_project_options_and_cached():
    from numba.core.caching import FunctionCache

    for module_name in KERNEL_MODULES:
        found = _dispatchers(module_name)
        assert found, module_name
        for name, d in found.items():
            assert isinstance(d._cache, FunctionCache), f"{module_name}.{name} is not cached"
            opts = d.targetoptions
            assert (opts["nogil"], opts["error_model"], opts["fastmath"]) == (
                True, "numpy", False), f"{module_name}.{name}"  # fmt: skip


def test_a_second_process_loads_the_kernels_from_the_cache():
    """This process compiled (or loaded) every kernel with a signature when it imported them;
    a new process finds all of them in the cache and compiles none."""
    import subprocess
    import sys

    for module_name in KERNEL_MODULES:
        _dispatchers(module_name)  # imported (compiled and cached) here first
    code = (
        "import importlib, sys\n"
        "from numba.core.registry import CPUDispatcher\n"
        "miss = []\n"
        f"for m in {KERNEL_MODULES!r}:\n"
        "    for n, d in vars(importlib.import_module(m)).items():\n"
        "        if isinstance(d, CPUDispatcher) and d.__module__ == m and d.signatures:\n"
        "            if sum(d.stats.cache_misses.values()) or not d.stats.cache_hits:\n"
        "                miss.append(m + '.' + n)\n"
        "print(' '.join(miss))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=600).stdout.strip()  # fmt: skip
    assert out == ""
