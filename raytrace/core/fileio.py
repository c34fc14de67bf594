"""Files in and out: atomic writes (a reader never sees a half-written file) and YAML reading with
one-line errors."""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path
from typing import Any

from hallray.errors import brief

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
    """PyYAML's safe loader with YAML 1.2 numbers (``1.0e9``, ``1e-3`` and ``.5`` are floats; PyYAML
    follows YAML 1.1, where an exponent needs a sign and a dot: ``1.0e9`` is a string), that
    refuses a key given twice in one mapping (YAML forbids it; PyYAML keeps the last silently) and
    a document whose aliases expand to more than the ``yaml values`` limit of
    :mod:`hallray.limits` (a "billion laughs" file), before anything is built from it."""
    import re

    import yaml
    from yaml.constructor import ConstructorError

    class Loader(yaml.SafeLoader):
        def construct_mapping(self, node: Any, deep: bool = False) -> Any:
            if isinstance(node, yaml.MappingNode):
                _refuse_duplicate_keys(self, node, ConstructorError)
            return super().construct_mapping(node, deep=deep)

        def get_single_data(self) -> Any:
            node = self.get_single_node()
            if node is None:
                return None
            _check_expansion(node, ConstructorError)
            return self.construct_document(node)

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


def _refuse_duplicate_keys(loader: Any, node: Any, error: type[Exception]) -> None:
    """Raise ``error`` for a scalar key given twice in one mapping node (merged ``<<`` keys may
    be overridden, as YAML allows)."""
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge" or not hasattr(key_node.value, "strip"):
            continue
        key = loader.construct_object(key_node)
        try:
            first = seen.setdefault(key, key_node.start_mark.line)
        except TypeError:  # an unhashable key: PyYAML refuses it itself
            continue
        if first != key_node.start_mark.line:
            raise error(
                None, None,
                f"key {brief(key)} given twice (lines {first + 1} and "
                f"{key_node.start_mark.line + 1}): give it once",
                key_node.start_mark,
            )  # fmt: skip


def _children(node: Any) -> list[Any]:
    """The nodes under a YAML node (a mapping's keys and values, a sequence's items)."""
    if not isinstance(node.value, list):
        return []  # a scalar
    return [k for item in node.value for k in (item if isinstance(item, tuple) else (item,))]


def _check_expansion(root: Any, error: type[Exception]) -> None:
    """Refuse a node graph whose aliases expand to more values than the ``yaml values`` limit,
    or that refers to itself. Sizes are memoised per node (an alias is the same node object), so
    the check is linear in the file, not in the expansion."""
    from hallray.limits import LIMITS, overridden

    limit = LIMITS["yaml values"].maximum
    size: dict[int, int] = {}
    busy: set[int] = set()  # on the current path from the root
    stack: list[tuple[Any, bool]] = [(root, False)]
    while stack:
        node, expanded = stack.pop()
        key = id(node)
        if expanded:
            busy.discard(key)
            size[key] = 1 + sum(size[id(k)] for k in _children(node))
            if size[key] > limit and not overridden():
                raise error(
                    None, None,
                    f"its aliases expand to more than {limit:,} values (the 'yaml values' "
                    "limit of docs/reliability.md): write the values out",
                    node.start_mark,
                )  # fmt: skip
            continue
        if key in size:
            continue
        if key in busy:
            raise error(None, None, "an alias refers to a value that contains it", node.start_mark)
        busy.add(key)
        stack.append((node, True))
        stack += [(k, False) for k in _children(node) if id(k) not in size]


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
