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

Inputs are sacred (:func:`check_output`, one rule for every command): an output may not be,
contain or lie inside an input file or directory of the command, may not be or contain the working
directory, the user's home, ``/``, the Python installation or the installed package, and may not
lie inside the installed package. A directory output carries a marker (:data:`MARKER`: the
command and the files it wrote); an existing non-empty directory is replaced only when its marker
says the same command wrote it and it holds nothing else (:func:`foreign_reason`), never a
directory with someone else's files, whatever ``--force`` says.
"""

from __future__ import annotations

import errno
import fcntl
import importlib.util
import json
import os
import re
import shutil
import stat
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from functools import lru_cache
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
    inputs : files or directories the command reads (None entries, ``-`` and paths that do not
        exist are skipped)
    directory : the output is a directory (else a regular file)
    what : how messages name the output (e.g. ``--export-glb``)

    Raises
    ------
    OutputError
        A special file (or the wrong kind) at the path, a symlink loop, a missing parent folder,
        an output that is, contains or lies inside an input, or one that is or contains a
        protected directory (:func:`protected_dirs`) or lies inside the installed package.
    """
    if os.fspath(path) == STDOUT:
        raise OutputError(f"{what}: '-' (stdout) is not possible here: name a file")
    real = _real(path)
    if os.path.islink(real):  # realpath stops at a link it cannot follow: a loop
        raise OutputError(f"{what} {path} is a symlink loop: refusing to replace it")
    if real.exists():
        mode = real.stat().st_mode
        ok = stat.S_ISDIR(mode) if directory else stat.S_ISREG(mode)
        if not ok:
            kind = "not a directory" if directory and stat.S_ISREG(mode) else _kind(mode)
            raise OutputError(f"{what} {path} is {kind}: refusing to replace it")
    if not real.parent.is_dir():
        where = "parent directory" if directory else "output directory"
        raise OutputError(f"{what} {path}: {where} does not exist: {real.parent}")
    _check_inputs(real, path, inputs, what)
    _check_protected(real, path, what)
    return real


def _check_inputs(real: Path, path: PathLike, inputs: Iterable[PathLike | None], what: str) -> None:
    """The output may not be an input, contain one, or lie inside an input directory."""
    found = []
    for item in inputs:
        if item is None or os.fspath(item) == STDOUT or not os.path.lexists(item):
            continue
        src = _real(item)
        if _same(real, src):
            found.append((0, "is an input of this command", item))
        elif real in src.parents:
            found.append((1, "contains an input of this command", item))
        elif src.is_dir() and src in real.parents:
            found.append((2, "is inside an input directory of this command", item))
    if found:
        _, why, item = min(found, key=lambda f: f[0])  # the most direct reason first
        raise OutputError(
            f"{what} {path} {why} ({item}): refusing to write there; choose another output"
        )


def _check_protected(real: Path, path: PathLike, what: str) -> None:
    """The output may not be or contain a protected directory, nor lie inside the package."""
    for d, name in protected_dirs():
        if _same(real, d) or real in d.parents:
            verb = "is" if _same(real, d) else "contains"
            raise OutputError(
                f"{what} {path} {verb} {name} ({d}): refusing to write there; choose another "
                "output"
            )
    for d in package_dirs():
        if d in real.parents:
            raise OutputError(
                f"{what} {path} is inside the installed package ({d}): choose an output outside it"
            )


@lru_cache(maxsize=1)
def package_dirs() -> tuple[Path, ...]:
    """The directories of the installed packages (hallray, raytrace, positioning and the bundled
    scenes), found without importing raytrace or positioning."""
    dirs = [Path(__file__).resolve().parent]
    for name in ("raytrace", "positioning"):
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            spec = None
        for loc in (spec.submodule_search_locations or []) if spec is not None else []:
            dirs.append(_real(loc))
    scenes = [d.parent / "scenes" for d in dirs if d.name == "raytrace"]
    dirs += [s.resolve() for s in scenes if (s / "hall.yaml").is_file()]  # a source checkout
    return tuple(dict.fromkeys(dirs))


def protected_dirs() -> list[tuple[Path, str]]:
    """(directory, what it is) that no output may be or contain: ``/``, the working directory,
    the user's home, the Python installation (its prefixes) and the installed package."""
    out = [(Path("/"), "the root directory")]
    try:
        out.append((_real(os.getcwd()), "the working directory"))
    except OSError:  # the working directory was removed
        pass
    home = os.path.expanduser("~")
    if home and home != "~":
        out.append((_real(home), "the home directory"))
    for prefix in dict.fromkeys((sys.prefix, sys.base_prefix, sys.exec_prefix)):
        out.append((_real(prefix), "the Python installation"))
    out += [(d, "the installed package") for d in package_dirs()]
    return out


#: The marker every directory output carries: the command that wrote it and its files.
MARKER = ".hallray-output.json"


def _listing(folder: Path) -> list[str]:
    """Everything under ``folder`` (relative paths, folders with a trailing ``/``), sorted;
    symlinks are listed, not followed."""
    out = []
    for root, dirs, files in os.walk(folder):
        rel = Path(root).relative_to(folder)
        out += [f"{(rel / d).as_posix()}/" for d in dirs]
        out += [(rel / f).as_posix() for f in files]
    return sorted(out)


def write_marker(folder: Path, command: str, *, listed: bool = True) -> None:
    """Write :data:`MARKER` into ``folder``: ``command`` and (``listed``) the files it holds now
    (a resumable output such as a sweep's is marked without a list: it is never replaced)."""
    files = [f for f in _listing(folder) if f != MARKER] if listed else None
    doc = {"schema": "hallray-output", "version": 1, "command": command, "files": files}
    (folder / MARKER).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")


def read_marker(folder: Path) -> dict[str, Any] | None:
    """The marker of a directory output, or None (absent or not a marker)."""
    try:
        doc = json.loads((folder / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("schema") != "hallray-output":
        return None
    return doc


def foreign_reason(folder: Path, command: str) -> str | None:
    """Why the non-empty directory ``folder`` is not an earlier output of ``command`` that may be
    replaced (no marker, another command's, or files the marker does not list), or None."""
    doc = read_marker(folder)
    if doc is None:
        return f"was not written by {command} (no {MARKER} in it)"
    if doc.get("command") != command:
        return f"was written by {doc.get('command')}, not {command}"
    listed = doc.get("files")
    if not isinstance(listed, list):
        return None
    extra = sorted(set(_listing(folder)) - set(listed) - {MARKER})
    if extra:
        more = f" and {len(extra) - 1} more" if len(extra) > 1 else ""
        return f"holds files {command} did not write ({extra[0]}{more})"
    return None


def check_output_dir(
    path: PathLike, *, command: str, inputs: Iterable[PathLike | None] = (), force: bool = False,
    replace_previous: bool = False, what: str = "output directory",
) -> Path:  # fmt: skip
    """Check a directory output before any work (:func:`check_output`, then: an existing
    non-empty directory must be an earlier output of ``command`` with nothing else in it, and is
    replaced only with ``force`` or, for commands that replace their previous output,
    ``replace_previous``). Returns the path with its symlinks followed."""
    real = check_output(path, inputs=inputs, directory=True, what=what)
    if real.is_dir() and any(real.iterdir()):
        reason = foreign_reason(real, command)
        if reason is not None:
            even = " (--force replaces only an earlier output of the same command)" if force else ""
            raise OutputError(
                f"{what} {path} is not empty and {reason}: refusing to replace it{even}; "
                "choose another output or empty it yourself"
            )
        if not (force or replace_previous):
            raise OutputError(
                f"{what} {path} holds an earlier {command} output (use --force to replace it)"
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
    path: PathLike, *, command: str = "hallray", force: bool = False,
    inputs: Iterable[PathLike | None] = (), replace_previous: bool = False,
    what: str = "output directory",
) -> Iterator[Path]:  # fmt: skip
    """Build a directory output whole or not at all.

    Yields an empty temporary directory beside ``path`` (mode ``0777 & ~umask``); when the block
    ends normally the marker (:func:`write_marker`) is written into it and it is renamed to
    ``path`` (replacing the previous one), otherwise removed.

    Parameters
    ----------
    path : the output directory
    command : the command writing it (recorded in the marker; only its own earlier output is
        ever replaced)
    force : replace an earlier non-empty output of ``command`` (``--force``)
    inputs : what the command reads (the output may neither be, contain nor lie inside one)
    replace_previous : replace an earlier output of ``command`` without ``force`` (a report)
    what : how messages name the output

    Raises
    ------
    OutputError
        Refused output (:func:`check_output_dir`), or another process writing the same output.
    """
    real = check_output(path, inputs=inputs, directory=True, what=what)
    with output_lock(real):
        _cleanup_stale(real)
        check_output_dir(path, command=command, inputs=inputs, force=force,
                         replace_previous=replace_previous, what=what)  # fmt: skip
        tmp = Path(tempfile.mkdtemp(prefix=f".{real.name}.", suffix=".tmp", dir=real.parent))
        try:
            os.chmod(tmp, 0o777 & ~umask())
            yield tmp
            write_marker(tmp, command)
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
