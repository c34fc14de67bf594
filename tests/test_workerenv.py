"""hallray.workerenv: variables set for the workers started within the block, restored after."""

import os
import subprocess
import sys

import pytest

from hallray.workerenv import ONE_THREAD, environ_set


def test_a_child_started_within_sees_the_values_and_the_caller_gets_its_own_back(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "7")
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    with environ_set(ONE_THREAD):
        seen = subprocess.run([sys.executable, "-c", "import os; print(os.environ['OMP_NUM_THREADS'],"
                               " os.environ['OPENBLAS_NUM_THREADS'])"],
                              capture_output=True, text=True, check=True).stdout.split()  # fmt: skip
    assert seen == ["1", "1"]
    assert os.environ["OMP_NUM_THREADS"] == "7" and "OPENBLAS_NUM_THREADS" not in os.environ


def test_restored_when_the_block_raises(monkeypatch):
    monkeypatch.delenv("HALLRAY_TEST_VAR", raising=False)
    with pytest.raises(RuntimeError), environ_set({"HALLRAY_TEST_VAR": "x"}):
        assert os.environ["HALLRAY_TEST_VAR"] == "x"
        raise RuntimeError
    assert "HALLRAY_TEST_VAR" not in os.environ
