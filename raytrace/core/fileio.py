"""Files in and out: atomic writes (a reader never sees a half-written file) and YAML reading with
one-line errors."""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path
from typing import Any

from .errors import HallrayError


def write_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same directory and
    ``os.replace``. A symlink at ``path`` is followed (its target is replaced, the link stays); a
    device node, FIFO, socket or directory there is refused. The file gets the mode an ordinary
    ``open()`` would give it (``0666 & ~umask``) or keeps the mode of the file it replaces; a
    missing directory is a one-line :class:`HallrayError`. (The command-line tools go through
    :mod:`hallray.safe_output`, which also refuses inputs and locks; this is the library's writer.)
    """
    p = Path(os.path.realpath(os.fspath(path)))
    if p.exists() and not stat.S_ISREG(p.stat().st_mode):
        raise HallrayError(f"output {path} is not a regular file: refusing to replace it")
    parent = p.parent
    if not parent.is_dir():
        raise HallrayError(f"output directory does not exist: {Path(path).parent}")
    fd, tmp = tempfile.mkstemp(dir=parent, prefix=f".{p.name}.", suffix=".tmp")
    try:
        # mkstemp creates 0600
        if p.exists():
            mode = p.stat().st_mode & 0o777
        else:
            umask = os.umask(0o022)
            os.umask(umask)
            mode = 0o666 & ~umask
        os.chmod(tmp, mode)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, p)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _yaml12_loader() -> type:
    """PyYAML's safe loader with YAML 1.2 numbers: ``1.0e9``, ``1e-3`` and ``.5`` are floats
    (PyYAML follows YAML 1.1, where an exponent needs a sign and a dot: ``1.0e9`` is a string)."""
    import re

    import yaml

    class Loader(yaml.SafeLoader):
        pass

    float12 = re.compile(
        r"^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?"
        r"|[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)"
        r"|[-+]?\.[0-9_]+(?:[eE][-+]?[0-9]+)?"
        r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"
    )
    Loader.yaml_implicit_resolvers = {
        k: [(tag, rx) for tag, rx in v if tag != "tag:yaml.org,2002:float"]
        for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()
    }
    Loader.add_implicit_resolver("tag:yaml.org,2002:float", float12, list("-+0123456789."))
    return Loader


def read_yaml(
    path: str | os.PathLike[str], what: str, error: type[HallrayError] = HallrayError
) -> Any:
    """The content of a YAML (or JSON) file, with one-line errors.

    Numbers follow YAML 1.2 (``1.0e9`` is a float), a UTF-8 byte-order mark is accepted, and a
    missing file, an unreadable one or bad YAML raise ``error`` naming ``what`` and the file
    (``cannot read <what>: not found: <path>``, ``cannot read <what> <path>: invalid YAML at line
    <n>: <problem>``).
    """
    import yaml

    p = Path(path)
    if not p.exists():
        raise error(f"cannot read {what}: not found: {p}")
    try:
        text = p.read_text(encoding="utf-8-sig")
        return yaml.load(text, Loader=_LOADER.setdefault("yaml12", _yaml12_loader()))  # noqa: S506
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or " ".join(str(exc).split()) or "parse error"
        raise error(f"cannot read {what} {p}: invalid YAML{where}: {problem}") from None
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise error(f"cannot read {what} {p}: {' '.join(str(reason).split())}") from None


_LOADER: dict[str, type] = {}
