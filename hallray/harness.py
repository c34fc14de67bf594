"""The command-line harness of every hallray tool: one-line errors, exit codes, signals.

One harness for the commands of both packages (``raytrace.cli.harness.run_tool`` and
``positioning.cli`` run on it; standard library only, cheap to import). A tool is a function
``main(args) -> int`` and an :class:`OneLineParser`; :func:`run_command` runs it:

* bad input (an :class:`~hallray.errors.InputError`, e.g. ``positioning.PositioningError``, or
  one of the error types the caller lists) -> ``error: <one line>`` on stderr, exit status 2
  (:data:`EXIT_BAD_INPUT`), never a traceback;
* argparse usage errors -> one line, exit status 2; ``--help`` -> 0;
* an unwritable output, a full disk (``OSError``) -> one line, exit status 2;
* memory exhausted (``MemoryError``, which the size limits of :mod:`hallray.limits` should have
  prevented) -> one line, exit status 2;
* Ctrl-C and SIGTERM -> ``error: interrupted``, exit status 130 (:data:`EXIT_INTERRUPTED`),
  after the tool's own clean-up (``finally`` blocks) ran;
* a closed stdout (``tool | head``) -> no message, exit status 141 (:data:`EXIT_BROKEN_PIPE`,
  like a process killed by SIGPIPE);
* warnings -> ``warning: <message>`` lines.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any, NoReturn

from .errors import InputError

EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141

#: Option values that start with '-' but are numbers or comma-separated numbers (``-1,2,1.5``)
#: or minus infinity (``--min-power-db -inf``): argparse would take them for an option.
_NEGATIVE_VALUE = re.compile(r"^-((\d|\.\d)[\d.,eE+-]*|inf|infinity)$", re.IGNORECASE)

#: The program name the next :func:`run_command` shows in its usage line (``hallray trace``
#: when the ``hallray`` command runs a tool; None: the tool's own name).
_PROG: ContextVar[str | None] = ContextVar("hallray_command_name", default=None)


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (``error: ...``, exit status 2), and
    that takes negative numbers and negative comma-separated coordinates as option values."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # argparse recognises only plain negative numbers as values; coordinates like -1,2,1.5
        # are values too (no option of ours looks like a negative number)
        self._negative_number_matcher = _NEGATIVE_VALUE

    def error(self, message: str) -> NoReturn:
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(EXIT_BAD_INPUT)


#: Longest error line shown; the rest is cut (a message never prints an unbounded value).
MAX_MESSAGE_CHARS = 1000


def one_line(exc: BaseException) -> str:
    """The message of an error as one line (an ``OSError`` names its file), at most
    :data:`MAX_MESSAGE_CHARS` characters."""
    if isinstance(exc, OSError):
        text = exc.strerror or str(exc)
        text = f"{text}: {exc.filename}" if exc.filename else text
    else:
        text = str(exc).strip() or type(exc).__name__
    text = " ".join(text.split())
    if len(text) > MAX_MESSAGE_CHARS:
        text = f"{text[:MAX_MESSAGE_CHARS]}... ({len(text) - MAX_MESSAGE_CHARS:,} characters cut)"
    return text


@contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt in the main thread, so that clean-up code runs."""

    def handler(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextmanager
def command_name(prog: str) -> Iterator[None]:
    """Run a tool under another program name: the first :func:`run_command` inside shows
    ``prog`` in its usage and help (the ``hallray`` command's ``hallray trace`` for
    ``trace-scene``); a tool that runs another tool inside keeps that one's own name."""
    token = _PROG.set(prog)
    try:
        yield
    finally:
        _PROG.reset(token)


def run_command(
    main: Callable[[argparse.Namespace], int],
    parser: argparse.ArgumentParser,
    argv: Sequence[str] | None,
    *,
    user_errors: tuple[type[BaseException], ...] = (),
    interrupted: str = "interrupted",
) -> int:
    """Parse ``argv`` and run ``main(args)``; return the exit status (see the module docstring).

    Parameters
    ----------
    main : the tool, ``main(args) -> int``
    parser : its argument parser (a :class:`OneLineParser`)
    argv : arguments (None: ``sys.argv[1:]``)
    user_errors : exception types that mean bad input (besides :class:`InputError`)
    interrupted : what to say after Ctrl-C or SIGTERM (e.g. what was kept)
    """
    prog = _PROG.get()
    if prog is not None:  # once: a tool run inside this one keeps its name
        parser.prog = prog
        _PROG.set(None)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help (0) or a usage error (2, already printed)
        return exc.code if isinstance(exc.code, int) else EXIT_BAD_INPUT
    bad_input = (InputError, *user_errors)
    try:
        with _sigterm_as_interrupt(), warnings.catch_warnings():
            warnings.simplefilter("default")
            warnings.formatwarning = lambda msg, *a, **k: f"warning: {msg}\n"  # type: ignore[assignment]
            return int(main(args))
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_BROKEN_PIPE
    except bad_input as exc:
        print(f"error: {one_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:  # unwritable output, a full disk: one line, not a traceback
        print(f"error: {one_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError:  # the limits (hallray.limits) should have refused it up front
        print(
            "error: out of memory: the run needs more memory than this machine has; reduce its "
            "size (the size limits are in docs/reliability.md)",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"error: {interrupted}", file=sys.stderr)
        return EXIT_INTERRUPTED


def _silence_stdout() -> None:
    """After a broken pipe, point stdout at /dev/null so that the interpreter's final flush does
    not print a second error."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
