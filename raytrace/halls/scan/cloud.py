"""Reading point clouds (.ply, .pcd, .xyz, .pts; .las/.laz with laspy) and importing the
optional open3d with a one-line error when it is missing.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import HallrayError
from .options import CLOUD_SUFFIXES


def import_open3d() -> Any:
    """Import open3d or raise a one-line :class:`HallrayError` saying how to get it."""
    try:
        import open3d as o3d
    except (ImportError, OSError) as exc:
        raise HallrayError(
            "scan-to-scene needs open3d: pip install 'hallray[scan]' (on Debian/Ubuntu also "
            f"apt-get install libusb-1.0-0); import failed: {exc}".splitlines()[0]
        ) from None
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    return o3d


def read_cloud(path: str | os.PathLike[str]) -> np.ndarray:
    """Points of a point-cloud file.

    Parameters
    ----------
    path : .ply or .pcd (read with open3d), .xyz (``x y z [...]`` per line), .pts (optional count
        line, then ``x y z [intensity r g b]``), .las / .laz (with laspy; .laz also needs a LAZ
        backend such as lazrs)

    Returns
    -------
    (N, 3) float64, metres (non-finite rows included; :func:`reconstruct` drops them)

    Raises
    ------
    HallrayError
        Missing file, unknown format, a file that is not a point cloud, an empty cloud.
    """
    p = Path(path)
    if not p.is_file():
        raise HallrayError(f"point cloud not found: {path}")
    suffix = p.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise HallrayError(
            f"unsupported point-cloud format {suffix or '(none)'!r} for {p.name}; "
            f"use one of {', '.join(CLOUD_SUFFIXES)}"
        )
    if suffix in (".xyz", ".pts"):
        pts = _read_text_cloud(p, skip_count=suffix == ".pts")
    elif suffix in (".las", ".laz"):
        pts = _read_las(p)
    else:
        pts = _read_open3d_cloud(p, suffix)
    if len(pts) == 0:
        raise HallrayError(f"point cloud {p.name} has no points")
    return pts


def _read_text_cloud(p: Path, *, skip_count: bool) -> np.ndarray:
    try:
        text = p.read_text()
    except UnicodeDecodeError:
        raise HallrayError(f"{p.name} is not a text point cloud (binary content)") from None
    lines = text.splitlines()
    start = 0
    # a .pts file starts with the number of points on a line of its own
    while start < len(lines) and not lines[start].strip():
        start += 1
    if skip_count and start < len(lines) and len(lines[start].split()) == 1:
        start += 1
    body = "\n".join(ln for ln in lines[start:] if ln.strip() and not ln.lstrip().startswith("#"))
    if not body:
        return np.zeros((0, 3))
    try:
        data = np.loadtxt(io.StringIO(body.replace(",", " ")), ndmin=2, usecols=(0, 1, 2))
    except (ValueError, IndexError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise HallrayError(f"{p.name} is not a point cloud (x y z per line): {first}") from None
    return np.asarray(data, dtype=float)


def _read_open3d_cloud(p: Path, suffix: str) -> np.ndarray:
    with open(p, "rb") as fh:
        head = fh.read(4096)
    if suffix == ".ply" and not head.startswith(b"ply"):
        raise HallrayError(f"{p.name} is not a PLY file (no 'ply' header)")
    if suffix == ".pcd" and (b"FIELDS" not in head or b"DATA" not in head):
        raise HallrayError(f"{p.name} is not a PCD point cloud (no FIELDS/DATA header)")
    o3d = import_open3d()
    cloud = o3d.io.read_point_cloud(str(p))
    pts = np.asarray(cloud.points, dtype=float).reshape(-1, 3)
    if len(pts) == 0 and b"element vertex 0" not in head and b"POINTS 0" not in head:
        raise HallrayError(f"cannot read points from {p.name} (damaged or not a point cloud)")
    return pts


def _read_las(p: Path) -> np.ndarray:
    try:
        import laspy
    except ImportError:
        raise HallrayError(f"reading {p.name} needs laspy: pip install laspy") from None
    try:
        las = laspy.read(str(p))
    except Exception as exc:  # laspy raises many types (LaspyException, ValueError, OSError)
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise HallrayError(f"cannot read {p.name}: {first}") from None
    return np.column_stack([las.x, las.y, las.z]).astype(float)
