"""The command-line harness shared by every tool (hallray.harness)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import pytest

from hallray.errors import InputError
from hallray.harness import (
    EXIT_BAD_INPUT,
    EXIT_BROKEN_PIPE,
    EXIT_INTERRUPTED,
    OneLineParser,
    run_command,
)
from positioning.errors import PositioningError


class _Custom(ValueError):
    pass


def _parser() -> OneLineParser:
    p = OneLineParser(prog="tool")
    p.add_argument("--xyz")
    p.add_argument("--n", type=float)
    return p


def test_negative_coordinates_and_numbers_are_values():
    args = _parser().parse_args(["--xyz", "-1,2,1.5", "--n", "-3e2"])
    assert args.xyz == "-1,2,1.5" and args.n == -300.0
    assert _parser().parse_args(["--xyz", "-.5,-2,-1e-3"]).xyz == "-.5,-2,-1e-3"


def test_usage_errors_are_one_line(capsys):
    assert run_command(lambda a: 0, _parser(), ["--bogus"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1
    assert run_command(lambda a: 0, _parser(), ["--help"]) == 0


@pytest.mark.parametrize(
    "exc, code, text",
    [
        (PositioningError("bad\nthing"), EXIT_BAD_INPUT, "error: bad thing\n"),
        (InputError("any package's bad input"), EXIT_BAD_INPUT, "error: any package's bad input\n"),
        (_Custom("custom input error"), EXIT_BAD_INPUT, "error: custom input error\n"),
        (FileNotFoundError(2, "No such file or directory", "x.csv"), EXIT_BAD_INPUT,
         "error: No such file or directory: x.csv\n"),
        (KeyboardInterrupt(), EXIT_INTERRUPTED, "error: interrupted\n"),
    ],
)  # fmt: skip
def test_errors_become_one_line_and_an_exit_status(capsys, exc, code, text):
    def main(args):
        raise exc

    assert run_command(main, _parser(), [], user_errors=(_Custom,)) == code
    assert capsys.readouterr().err == text


def test_other_exceptions_are_not_hidden():
    def main(args):
        raise RuntimeError("a bug")

    with pytest.raises(RuntimeError):
        run_command(main, _parser(), [])


def _script(body: str) -> str:
    """A Python program running ``main`` (whose body is given) under the harness."""
    head = "import sys, time\nfrom hallray.harness import OneLineParser, run_command\n"
    main = "def main(args):\n" + textwrap.indent(textwrap.dedent(body).strip("\n"), "    ")
    tail = '\nsys.exit(run_command(main, OneLineParser(prog="t"), []))\n'
    return head + main + tail


def test_sigterm_runs_clean_up_and_exits_130(tmp_path):
    marker = tmp_path / "cleaned"
    code = _script(
        f"""
        try:
            print("ready", flush=True)
            time.sleep(30)
        finally:
            open({str(marker)!r}, "w").close()
        return 0
        """
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline().strip() == "ready"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == EXIT_INTERRUPTED
    assert err.strip() == "error: interrupted"
    assert marker.exists()


def test_closed_stdout_is_quiet():
    code = _script(
        """
        for i in range(100000):
            print("line", i)
        return 0
        """
    )
    r, w = os.pipe()
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=w, stderr=subprocess.PIPE)
    os.close(w)
    os.read(r, 10)
    os.close(r)  # the reader goes away, as `tool | head -1` does
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == EXIT_BROKEN_PIPE
    assert err == b""
