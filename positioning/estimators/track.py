"""``track``: a robust constant-velocity Kalman filter over the epochs of each device.

Any single-epoch method's fixes become ``METHOD+track`` (e.g. ``irls+track``): the fixes of one
device (one ``point`` of a dataset), in time order, are the measurements of a 2-D
constant-velocity Kalman filter; all devices are filtered at once (the state arrays carry a
device axis, the only Python loop is over epochs).

Model (per device, state ``s = (x, y, vx, vy)``, measurement ``z = (x, y)`` of the fix)::

    s_k = F(dt) s_{k-1} + w,   F = [[I, dt I], [0, I]],
    w ~ N(0, q [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]])      (white-noise acceleration, PSD q)
    z_k = H s_k + v,           H = [I 0],  v ~ N(0, sigma_m^2 I)

Robustness:

* **Innovation gate.** ``d^2 = nu^T S^-1 nu`` with the innovation ``nu = z - H s_pred`` and its
  covariance ``S = H P H^T + R``; a fix with ``d^2 > gate`` (default 5.99, the chi-square 95 %
  point with 2 degrees of freedom) is not used: the epoch reports the prediction and is flagged
  ``TRACK_GATED``. An NLoS epoch whose fix jumps by a metre is so rejected; 5 % of noise-only
  fixes are dropped too, which costs little (their mean is unbiased).
* **Restart.** After ``restart_after`` consecutive gated fixes (default 3) the device has really
  moved (or the track was wrong): the track restarts at the current fix with zero velocity
  (flag ``TRACK_RESTART``). This bounds the latency of a step larger than about
  ``sqrt(gate S)`` (0.85 m with the defaults at rest) to ``restart_after`` epochs; a noise-only
  device restarts with probability about ``0.05^restart_after`` per epoch.
* Unsolved fixes (NaN) are skipped: the filter predicts through them.

Latency (:func:`step_response`): a step larger than the gate (about 0.85 m with the defaults, at
rest) is followed after ``restart_after`` epochs (0.3 s at 10 Hz); a smaller step by the
filter's own dynamics (see ``docs/positioning.md`` for the measured figures). The z coordinate is not filtered: a tracked fix keeps its fix's z
(the known height of a 2D solve).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..errors import PositioningError
from .fixes import Fixes, Status, config_params

#: Suffix that turns a single-epoch method into its tracked form (``irls+track``).
SUFFIX = "+track"
#: Default standard deviation of a fix's error per coordinate, metres.
SIGMA_M = 0.3
#: Default power spectral density of the white-noise acceleration, m^2/s^3.
ACCEL_PSD = 0.2
#: Default innovation gate on d^2: the chi-square 95 % point with 2 degrees of freedom.
GATE = 5.99
#: Default number of consecutive gated fixes after which the track restarts.
RESTART_AFTER = 3
#: Time step used when the fixes carry no time (seconds; the datasets' 10 Hz).
DEFAULT_DT_S = 0.1
#: Initial velocity standard deviation of a (re)started track, m/s.
V0_MPS = 1.0

#: Parameters of the filter: name -> (default, meaning).
PARAMS: dict[str, tuple[float, str]] = {
    "sigma_m": (SIGMA_M, "fix error std per coordinate, m"),
    "accel_psd": (ACCEL_PSD, "white-noise acceleration PSD, m^2/s^3"),
    "gate": (GATE, "innovation gate on d^2 (chi-square 95 %, 2 dof)"),
    "restart_after": (RESTART_AFTER, "consecutive gated fixes before a restart"),
}


@dataclass(frozen=True)
class TrackConfig:
    """Settings of the filter (:func:`kalman_track`); the meaning of each is in :data:`PARAMS`.

    Attributes
    ----------
    sigma_m : float, m; accel_psd : float, m^2/s^3; gate : float; restart_after : int
    """

    sigma_m: float = SIGMA_M
    accel_psd: float = ACCEL_PSD
    gate: float = GATE
    restart_after: int = RESTART_AFTER


def split_method(name: str) -> tuple[str, bool]:
    """``("irls", True)`` for ``"irls+track"``, ``("irls", False)`` for ``"irls"``."""
    if name.endswith(SUFFIX):
        return name[: -len(SUFFIX)], True
    return name, False


def check_params(params: Mapping[str, Any]) -> TrackConfig:
    """The :class:`TrackConfig` of parameters as given (``--param track:NAME=VALUE``, strings or
    numbers): defaults filled in; each value a positive finite number (``restart_after`` an
    integer), else a one-line :class:`PositioningError`."""
    unknown = sorted(set(params) - set(PARAMS))
    if unknown:
        raise PositioningError(
            f"track has no parameter {unknown[0]!r}; parameters: {', '.join(PARAMS)}"
        )
    out: dict[str, float] = {}
    for k, (default, _) in PARAMS.items():
        v = params.get(k, default)
        try:
            f = float(v)
        except (TypeError, ValueError):
            raise PositioningError(f"track parameter {k!r} must be a number, got {v!r}") from None
        if not (np.isfinite(f) and f > 0) or (k == "restart_after" and not f.is_integer()):
            raise PositioningError(f"track parameter {k!r} must be positive, got {v!r}")
        out[k] = f
    return TrackConfig(
        sigma_m=out["sigma_m"], accel_psd=out["accel_psd"], gate=out["gate"],
        restart_after=int(out["restart_after"]),
    )  # fmt: skip


def _layout(device: np.ndarray, time_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Index (D, K) of each device's fixes in time order (-1 = padding), and their times."""
    dev_ids, inv = np.unique(np.asarray(device).astype(str), return_inverse=True)
    t = np.asarray(time_s, dtype=float)
    order = np.lexsort((np.arange(t.size), t, inv))
    counts = np.bincount(inv, minlength=dev_ids.size)
    K = int(counts.max()) if counts.size else 0
    idx = np.full((dev_ids.size, K), -1, dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    col = np.arange(order.size) - np.repeat(start, counts)
    idx[inv[order], col] = order
    tt = np.where(idx >= 0, t[np.maximum(idx, 0)], np.nan)
    return idx, tt, counts


def _q_matrix(dt: np.ndarray, q: float) -> np.ndarray:
    """(D, 4, 4) process noise of the white-noise acceleration model over ``dt`` (D,)."""
    Q = np.zeros((dt.size, 4, 4))
    a, b, c = q * dt**3 / 3.0, q * dt**2 / 2.0, q * dt
    for i in (0, 1):
        Q[:, i, i], Q[:, i, i + 2], Q[:, i + 2, i], Q[:, i + 2, i + 2] = a, b, b, c
    return Q


def kalman_track(
    xy: np.ndarray,
    device: np.ndarray,
    time_s: np.ndarray | None = None,
    config: TrackConfig = TrackConfig(),
) -> tuple[np.ndarray, np.ndarray]:
    """Filter the fixes of every device (causal: each output uses that epoch and earlier ones).

    Parameters
    ----------
    xy : (F, 2) float, metres -- single-epoch fixes; NaN rows are unsolved (skipped)
    device : (F,) -- device (point) label of each fix
    time_s : (F,) float, seconds, optional -- fix times; None or NaN: the fix order within its
        device at :data:`DEFAULT_DT_S`
    config : TrackConfig -- the filter's settings (:data:`PARAMS`)

    Returns
    -------
    xy_tracked : (F, 2) float, metres -- NaN before a device's first solved fix
    status : (F,) int -- :class:`Status` ``TRACK_GATED`` / ``TRACK_RESTART`` bits
    """
    xy = np.asarray(xy, dtype=float)
    F = xy.shape[0]
    t = np.arange(F, dtype=float) * DEFAULT_DT_S if time_s is None else np.asarray(time_s, float)
    if not np.isfinite(t).all():  # per device order at the default rate instead
        t = np.arange(F, dtype=float) * DEFAULT_DT_S
    idx, tt, _ = _layout(device, t)
    D, K = idx.shape
    out = np.full((F, 2), np.nan)
    status = np.zeros(F, dtype=np.int64)
    s = np.zeros((D, 4))
    P = np.zeros((D, 4, 4))
    live = np.zeros(D, dtype=bool)
    misses = np.zeros(D, dtype=np.int64)
    t_last = np.zeros(D)
    R = config.sigma_m**2
    P0 = np.diag([R, R, V0_MPS**2, V0_MPS**2])
    for k in range(K):
        ok = idx[:, k] >= 0
        z = np.where(ok[:, None], xy[np.maximum(idx[:, k], 0)], np.nan)
        has = ok & np.isfinite(z).all(axis=1)
        # predict the live tracks to this epoch
        dt = np.where(live & ok, np.maximum(tt[:, k] - t_last, 0.0), 0.0)
        s[:, :2] += dt[:, None] * s[:, 2:]
        Fm = np.broadcast_to(np.eye(4), (D, 4, 4)).copy()
        Fm[:, 0, 2] = Fm[:, 1, 3] = dt
        P = Fm @ P @ Fm.transpose(0, 2, 1) + _q_matrix(dt, config.accel_psd)
        t_last = np.where(ok, tt[:, k], t_last)
        # gate the fixes of live tracks
        nu = z - s[:, :2]
        S = P[:, :2, :2] + R * np.eye(2)
        Sinv = np.linalg.inv(S)
        d2 = np.einsum("di,dij,dj->d", nu, Sinv, nu)
        use = has & live & (d2 <= config.gate)
        gated = has & live & ~use
        misses = np.where(gated, misses + 1, np.where(has, 0, misses))
        restart = gated & (misses >= config.restart_after)
        start = has & (~live | restart)
        # Kalman update of the accepted fixes
        Kg = P[:, :, :2] @ Sinv  # (D, 4, 2)
        s_upd = s + np.einsum("dij,dj->di", Kg, np.where(use[:, None], nu, 0.0))
        P_upd = P - Kg @ P[:, :2, :]
        s = np.where(use[:, None], s_upd, s)
        P = np.where(use[:, None, None], P_upd, P)
        # (re)start tracks at their fix
        s[start] = np.column_stack([z[start], np.zeros((start.sum(), 2))])
        P[start] = P0
        misses[start] = 0
        live |= start
        rows = idx[ok, k]
        out[rows] = np.where(live[ok, None], s[ok, :2], np.nan)
        status[idx[gated & ~restart, k]] |= int(Status.TRACK_GATED)
        status[idx[restart, k]] |= int(Status.TRACK_RESTART)
    return out, status


def track_fixes(
    fixes: Fixes,
    device: np.ndarray,
    time_s: np.ndarray | None = None,
    config: TrackConfig = TrackConfig(),
) -> Fixes:
    """The tracked version of a method's fixes: :func:`kalman_track` on their (x, y).

    The result is a new :class:`Fixes` named ``<method>+track``: x, y tracked, z the fix's own
    (the last solved one of the device where the fix is unsolved), status = the fix's status
    plus the track's bits (``UNSOLVED`` only before the device's first solved fix); ``params``
    the method's and the filter's (``config``, from :func:`check_params` for parameters as given
    on the command line).
    """
    xy, st = kalman_track(fixes.xyz[:, :2], device, time_s, config)
    z = _carry_z(fixes.xyz[:, 2], device, time_s)
    xyz = np.column_stack([xy, np.where(np.isfinite(xy[:, 0]), z, np.nan)])
    status = fixes.status | st
    solved = np.isfinite(xy).all(axis=1)
    status = np.where(solved, status & ~int(Status.UNSOLVED), status | int(Status.UNSOLVED))
    params = {**fixes.params, **config_params(config)}
    return replace(fixes, xyz=xyz, status=status, method=fixes.method + SUFFIX, params=params)


def _carry_z(z: np.ndarray, device: np.ndarray, time_s: np.ndarray | None) -> np.ndarray:
    """Each fix's z, or the device's last finite z before it (NaN if none)."""
    t = np.arange(z.size, dtype=float) if time_s is None else np.asarray(time_s, float)
    if not np.isfinite(t).all():
        t = np.arange(z.size, dtype=float)
    idx, _, _ = _layout(device, t)
    out = np.array(z, dtype=float)
    last = np.full(idx.shape[0], np.nan)
    for k in range(idx.shape[1]):
        ok = idx[:, k] >= 0
        zk = np.where(ok, z[np.maximum(idx[:, k], 0)], np.nan)
        last = np.where(np.isfinite(zk), zk, last)
        out[idx[ok, k]] = last[ok]
    return out


def step_response(
    step_m: float,
    *,
    n_before: int = 50,
    n_after: int = 50,
    dt_s: float = DEFAULT_DT_S,
    tolerance_m: float = 0.1,
    config: TrackConfig = TrackConfig(),
) -> float:
    """Latency of the tracker for a noise-free step of ``step_m`` metres, seconds.

    A device at rest at the origin for ``n_before`` epochs jumps to ``(step_m, 0)``; the latency
    is the time from the first fix after the step until the tracked position is within
    ``tolerance_m`` of the new position for good (inf if never within ``n_after`` epochs).
    """
    n = n_before + n_after
    xy = np.zeros((n, 2))
    xy[n_before:, 0] = step_m
    out, _ = kalman_track(xy, np.zeros(n), np.arange(n) * dt_s, config)
    err = np.hypot(out[n_before:, 0] - step_m, out[n_before:, 1])
    bad = np.flatnonzero(err > tolerance_m)
    if bad.size == 0:
        return 0.0
    if bad[-1] == n_after - 1:
        return float("inf")
    return float((bad[-1] + 1) * dt_s)
