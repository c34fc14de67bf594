"""The one safe output layer of every hallray command (standard library only).

The commands of both packages write through it (``positioning`` never imports ``raytrace``, so it
lives in :mod:`hallray`), and so does ``raytrace.emulation.dataset`` for the final rename of a
dataset directory (:func:`commit_dir`). What it guarantees:

* a file is written to a temporary file in the same folder and renamed over the target, so a
  reader never sees half a file; a directory (a report, a dataset, ``reproduce-paper``) is built
  in a temporary directory beside the target and renamed: it appears whole or not at all;
* a symlink at the output is followed (the file it points to is replaced, the link stays);
* a device node, a FIFO, a socket (or, for a file, a directory) at the output is refused, and
  so is an output that is one of the command's inputs (or, for a directory, contains one);
* ``-`` means stdout where a single file is written (:func:`write_file` with ``stdout_ok``);
* new files get ``0666 & ~umask``, new directories ``0777 & ~umask``; a replaced file keeps its
  mode;
* two processes writing one output: the second gets a one-line error (an ``fcntl`` lock on
  ``.<name>.lock`` beside the output), not a silent loss;
* the temporary files are removed on any exception, Ctrl-C and SIGTERM (the command harness
  turns SIGTERM into ``KeyboardInterrupt``); what a SIGKILL leaves behind
  (``.<name>.XXXXXXXX.tmp``) is removed by the next run on the same output.
"""

from __future__ import annotations

import errno
import fcntl
import os
import re
import shutil
import stat
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, BinaryIO

from .errors import InputError

PathLike = str | os.PathLike[str]

#: The name stdout goes by on the command line.
STDOUT = "-"


class OutputError(InputError):
    """An output the layer refuses (special file, an input, locked, not empty): one line."""


def umask() -> int:
    """The process's file-mode creation mask (read without changing it for long)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISDIR, "a directory"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def _real(path: PathLike) -> Path:
    """The absolute path with every symlink followed (also a dangling one's target)."""
    return Path(os.path.realpath(os.fspath(path)))


def _same(a: Path, b: Path) -> bool:
    """Whether two resolved paths name one file (hard links included)."""
    if a == b:
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_output(
    path: PathLike, *, inputs: Iterable[PathLike | None] = (), directory: bool = False,
    what: str = "output",
) -> Path:  # fmt: skip
    """Check an output path before any work; return it with its symlinks followed.

    Parameters
    ----------
    path : the output named on the command line
    inputs : files or directories the command reads (None entries are skipped)
    directory : the output is a directory (else a regular file)
    what : how messages name the output (e.g. ``--export-glb``)

    Raises
    ------
    OutputError
        A special file (or the wrong kind) at the path, a missing parent folder, or an output that
        is one of the inputs (a directory output also may not contain an input).
    """
    if os.fspath(path) == STDOUT:
        raise OutputError(f"{what}: '-' (stdout) is not possible here: name a file")
    real = _real(path)
    if real.exists():
        mode = real.stat().st_mode
        ok = stat.S_ISDIR(mode) if directory else stat.S_ISREG(mode)
        if not ok:
            kind = "not a directory" if directory and stat.S_ISREG(mode) else _kind(mode)
            raise OutputError(f"{what} {path} is {kind}: refusing to replace it")
    if not real.parent.is_dir():
        where = "parent directory" if directory else "output directory"
        raise OutputError(f"{what} {path}: {where} does not exist: {real.parent}")
    for item in inputs:
        if item is None or os.fspath(item) == STDOUT:
            continue
        src = _real(item)
        if _same(real, src) or (directory and real in src.parents):
            raise OutputError(
                f"{what} {path} is an input of this command ({item}): refusing to overwrite it"
            )
    return real


@contextmanager
def output_lock(real: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``real``'s output (``.<name>.lock`` beside it) or raise
    :class:`OutputError` at once when another process holds it. The lock file is removed on
    release."""
    lock = real.parent / f".{real.name}.lock"
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666 & ~umask())
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EAGAIN, errno.EACCES):
                raise OutputError(
                    f"{real} is being written by another process (lock {lock}); "
                    "wait for it or choose another output"
                ) from None
            raise
        # the holder before us may have removed the file it locked: lock the current one
        try:
            if os.fstat(fd).st_ino == os.stat(lock).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    try:
        yield
    finally:
        try:
            os.unlink(lock)
        except OSError:
            pass
        os.close(fd)


def _stale(real: Path) -> list[Path]:
    """Temporary files or directories a killed run left beside ``real`` (call under its lock)."""
    pat = re.compile(rf"^\.{re.escape(real.name)}\.[A-Za-z0-9_]{{8}}\.(tmp|old)$")
    try:
        return [p for p in real.parent.iterdir() if pat.match(p.name)]
    except OSError:
        return []


def _remove(p: Path) -> None:
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        try:
            p.unlink()
        except OSError:
            pass


def _cleanup_stale(real: Path) -> None:
    for p in _stale(real):
        _remove(p)


Writer = Callable[[BinaryIO], Any]


def _as_writer(data: bytes | str | Writer) -> Writer:
    if isinstance(data, str):
        raw = data.encode("utf-8")
        return lambda fh: fh.write(raw)
    if isinstance(data, bytes | bytearray | memoryview):
        return lambda fh: fh.write(data)
    return data


def write_file(
    path: PathLike, data: bytes | str | Writer, *, inputs: Iterable[PathLike | None] = (),
    stdout_ok: bool = False, what: str = "output",
) -> Path | None:  # fmt: skip
    """Write one file safely (see the module docstring); ``data`` is bytes, text (UTF-8) or a
    function writing to a binary file object. Returns the path written (None for stdout)."""
    writer = _as_writer(data)
    if stdout_ok and os.fspath(path) == STDOUT:
        sys.stdout.flush()
        writer(sys.stdout.buffer)
        sys.stdout.buffer.flush()
        return None
    real = check_output(path, inputs=inputs, what=what)
    with output_lock(real):
        _cleanup_stale(real)
        replace_atomic(real, writer)
    return real


def replace_atomic(real: Path, writer: Writer) -> None:
    """Write through ``.<name>.XXXXXXXX.tmp`` in ``real``'s folder, fsync, rename over ``real``."""
    fd, tmp = tempfile.mkstemp(prefix=f".{real.name}.", suffix=".tmp", dir=real.parent)
    try:
        try:
            mode = real.stat().st_mode & 0o7777 if real.exists() else 0o666 & ~umask()
        except OSError:
            mode = 0o666 & ~umask()
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as fh:
            writer(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, real)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


@contextmanager
def output_dir(
    path: PathLike, *, force: bool = False, inputs: Iterable[PathLike | None] = (),
    replaceable: Callable[[Path], bool] | None = None, what: str = "output directory",
) -> Iterator[Path]:  # fmt: skip
    """Build a directory output whole or not at all.

    Yields an empty temporary directory beside ``path`` (mode ``0777 & ~umask``); when the block
    ends normally it is renamed to ``path`` (replacing the previous one), otherwise removed.

    Parameters
    ----------
    path : the output directory
    force : replace a non-empty existing directory
    inputs : what the command reads (the output may neither be nor contain one)
    replaceable : ``f(existing_dir) -> bool``: an existing non-empty directory this returns True
        for is replaced without ``force`` (e.g. a previous report)
    what : how messages name the output

    Raises
    ------
    OutputError
        Refused output (see :func:`check_output`), a non-empty directory without ``force``, or
        another process writing the same output.
    """
    real = check_output(path, inputs=inputs, directory=True, what=what)
    with output_lock(real):
        _cleanup_stale(real)
        if real.is_dir() and any(real.iterdir()) and not force:
            if replaceable is None or not replaceable(real):
                raise OutputError(f"{what} {path} is not empty (use --force to replace it)")
        tmp = Path(tempfile.mkdtemp(prefix=f".{real.name}.", suffix=".tmp", dir=real.parent))
        try:
            os.chmod(tmp, 0o777 & ~umask())
            yield tmp
            commit_dir(tmp, real)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise


def commit_dir(tmp: Path, real: Path) -> None:
    """Rename the finished temporary directory ``tmp`` to ``real`` (same parent folder); a
    previous ``real`` is moved aside first and removed after (a killed run leaves it as
    ``.<name>.XXXXXXXX.old``, which the next :func:`output_dir` on the same output removes)."""
    if real.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{real.name}.", suffix=".old", dir=real.parent))
        os.rename(real, old / "previous")
        os.rename(tmp, real)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.rename(tmp, real)
