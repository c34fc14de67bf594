"""JSON read strictly (standard library only): a key given twice in one object is an error, not
a silent last-wins (``meta.json``, a map's metadata, a sidecar). The YAML files have the same rule
(:func:`raytrace.core.fileio.read_yaml`)."""

from __future__ import annotations

import json
from typing import Any

from .errors import brief


class DuplicateKeyError(ValueError):
    """A key given twice in one JSON object (a ``ValueError``, as ``json.JSONDecodeError``)."""


def _pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise DuplicateKeyError(f"key {brief(k)} given twice in one object")
        out[k] = v
    return out


def loads(text: str | bytes) -> Any:
    """``json.loads`` that refuses duplicate keys (:class:`DuplicateKeyError`, a ValueError)."""
    return json.loads(text, object_pairs_hook=_pairs)
