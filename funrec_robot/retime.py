"""Time parametrisation: toppra along a joint-space path, ruckig between two states at rest.

toppra's default output (``ParametrizeSpline``) re-fits a spline through the gridpoints and overshoots the
acceleration limits between them, so paths are parametrised with ``ParametrizeConstAccel`` and the result is
re-checked on a dense sampling and slowed uniformly if anything still exceeds a limit. Ruckig is used
state-to-state only: its free version sends requests with intermediate waypoints to a cloud service, so none
is ever passed.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import ruckig

from funrec.errors import PlanningError
from funrec.typed import FloatArray

log = logging.getLogger(__name__)



@dataclass(frozen=True)
class RetimeConfig:
    """Settings of time parametrisation."""

    dt: float = 0.01
    """Sample period of the output trajectories, s."""
    check_dt: float = 0.001
    """Sample period of the dense limit check, s."""
    grid_factor: int = 4
    """toppra gridpoints per path waypoint."""
    min_gridpoints: int = 100
    """Fewest toppra gridpoints (the limits hold exactly only at gridpoints; the dense check covers the rest)."""
    jerk_per_acceleration: float = 8.0
    """Ruckig jerk limit as a multiple of each joint's acceleration limit, 1/s."""
    limit_tolerance: float = 1e-6
    """Relative excess over a limit still accepted on the dense check (round-off)."""
    overshoot_share: float = 0.5
    """The clamped cubic through the waypoints may leave the range of a coordinate's two waypoints on a piece by this
    share of the coordinate's step there (plus ``overshoot_margin``); where it leaves it by more, the cubic is
    redone on evenly spaced knots, and where that leaves it too, the path is interpolated shape-preservingly (PCHIP
    slopes, no overshoot, timed slower)."""
    overshoot_margin: float = 0.05
    """... plus this much, m or rad: the cubic's swings seen on paths that pass their checks are kept (TIAGo's arm
    joint 0.031 rad beyond two waypoints 0.011 apart on dark_rev_glass_wall_00, a base slide of Fetch's 14 mm), its
    gross ones not (Fetch's door state 0.177 rad below closed)."""


@dataclass(frozen=True)
class Trajectory:
    """Joint positions and velocities sampled at a fixed period from t = 0 (both ends at rest)."""

    t: FloatArray
    """(T,) sample times, s."""
    q: FloatArray
    """(T, n) positions, m or rad."""
    qd: FloatArray
    """(T, n) velocities, m/s or rad/s."""

    @property
    def duration(self) -> float:
        return float(self.t[-1]) if len(self.t) else 0.0


@dataclass(frozen=True)
class LimitUse:
    """Peak fraction of each limit used by a trajectory, measured on dense samples (1.0 = at the limit)."""

    velocity: float
    """max |qd| / v_max."""
    acceleration: float
    """max |qdd| / a_max (finite differences of velocity)."""
    jerk: float
    """max |qddd| / j_max, or 0 when no jerk limit is given."""


def limit_use(
    t: npt.ArrayLike, qd: npt.ArrayLike, v_max: npt.ArrayLike, a_max: npt.ArrayLike, j_max: npt.ArrayLike | None = None
) -> LimitUse:
    """Measure how much of the limits densely sampled velocities use.

    Args:
        t: (T,) increasing times, s.
        qd: (T, n) velocities.
        v_max, a_max: (n,) limits; j_max: (n,) jerk limits or None.
    """
    t = np.asarray(t, dtype=np.float64)
    qd = np.asarray(qd, dtype=np.float64)
    qdd = np.gradient(qd, t, axis=0) if len(t) > 2 else np.zeros_like(qd)
    use_j = 0.0
    if j_max is not None and len(t) > 3:
        qddd = np.diff(qdd, axis=0) / np.diff(t)[:, None]
        use_j = float(np.max(np.abs(qddd) / np.asarray(j_max)))
    return LimitUse(
        velocity=float(np.max(np.abs(qd) / np.asarray(v_max))),
        acceleration=float(np.max(np.abs(qdd) / np.asarray(a_max))),
        jerk=use_j,
    )


def _sample(timed, t: FloatArray, order: int = 0) -> FloatArray:  # noqa: ANN001
    """``timed(t, order)`` (order 0 or 1) of toppra's ``ParametrizeConstAccel``, its path parameter evaluated at all
    times at once. Hand-written from toppra's ``_eval_params``, which loops over the times in Python: checking a
    Fetch path of 50 s every ``check_dt`` took 1.8 s of its 19 gt18 plans. The same arithmetic in the same order,
    so the same samples bit for bit (``tests/test_plan_speed.py``)."""
    index = np.searchsorted(timed._ts, t, side="right") - 1
    index = np.where(index == len(timed._us), index - 1, index)
    dt = t - timed._ts[index]
    u, v = timed._us[index], timed._velocities[index]
    s = timed._ss[index] + dt * v + 0.5 * dt**2 * u
    return timed._path(s) if order == 0 else np.multiply(timed._path(s, 1), (v + dt * u)[:, np.newaxis])


def _path_parameter(waypoints: FloatArray, v_max: FloatArray) -> FloatArray:
    """Cumulative path parameter of waypoints: joint steps in units of each joint's speed limit."""
    steps = np.max(np.abs(np.diff(waypoints, axis=0)) / v_max, axis=1)
    steps = np.maximum(steps, 1e-6)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    return s / s[-1]


def _overshooting_pieces(path, ss: FloatArray, waypoints: FloatArray, config: RetimeConfig) -> np.ndarray:  # noqa: ANN001
    """(N - 1,) True for the spline pieces between waypoints on which some coordinate leaves the range of its two
    waypoints by more than ``overshoot_share`` of its step plus ``overshoot_margin`` (sampled at 8 inner points)."""
    u = np.linspace(0.0, 1.0, 10)[1:-1]
    s = (ss[:-1, None] + np.diff(ss)[:, None] * u).ravel()
    q = np.asarray(path(s)).reshape(len(ss) - 1, len(u), -1)
    step = np.abs(np.diff(waypoints, axis=0))[:, None, :]
    room = config.overshoot_share * step + config.overshoot_margin
    low = np.minimum(waypoints[:-1], waypoints[1:])[:, None, :] - room
    high = np.maximum(waypoints[:-1], waypoints[1:])[:, None, :] + room
    return np.any((q < low) | (q > high), axis=(1, 2))


def _spread_waypoints(waypoints: FloatArray, min_step: float) -> FloatArray:
    """The waypoints without the inner ones closer than ``min_step`` (max-norm) to the last one kept."""
    kept = [0]
    for i in range(1, len(waypoints) - 1):
        if np.max(np.abs(waypoints[i] - waypoints[kept[-1]])) >= min_step:
            kept.append(i)
    if len(kept) > 1 and np.max(np.abs(waypoints[-1] - waypoints[kept[-1]])) < min_step:
        kept.pop()  # the last inner one kept sits on the end: the end stays exact
    return waypoints[kept + [len(waypoints) - 1]]


def retime_path(
    waypoints: npt.ArrayLike, v_max: npt.ArrayLike, a_max: npt.ArrayLike, config: RetimeConfig = RetimeConfig()
) -> Trajectory:
    """Fastest rest-to-rest timing of a joint path under velocity and acceleration limits (toppra).

    The waypoints are joined by a clamped cubic spline, toppra's reachability analysis gives the path
    velocity at its gridpoints, ``ParametrizeConstAccel`` turns that into time, and a dense check at
    ``check_dt`` scales time up uniformly until no limit is exceeded (time scaling by k divides
    velocities by k and accelerations by k^2).

    Args:
        waypoints: (N, n) joint positions, N >= 2.
        v_max, a_max: (n,) limits.

    Where toppra finds no parametrisation (see below), the path is driven rest to rest between its waypoints.
    """
    # toppra imports matplotlib.pyplot at import time (about a second): only when a path is timed.
    import toppra
    import toppra.algorithm
    import toppra.constraint

    waypoints = np.asarray(waypoints, dtype=np.float64)
    v_max = np.asarray(v_max, dtype=np.float64)
    a_max = np.asarray(a_max, dtype=np.float64)
    if waypoints.ndim != 2 or len(waypoints) < 2:
        raise ValueError(f"waypoints: expected (N >= 2, n), got {waypoints.shape}")
    if np.max(np.abs(waypoints - waypoints[0])) < 1e-9:
        return Trajectory(np.zeros(1), waypoints[:1].copy(), np.zeros((1, waypoints.shape[1])))
    # Repeated waypoints give the spline zero-length pieces, which toppra cannot time.
    moved = np.r_[True, np.max(np.abs(np.diff(waypoints, axis=0)), axis=1) > 1e-9]
    waypoints = waypoints[moved]
    ss = _path_parameter(waypoints, v_max)
    path = toppra.SplineInterpolator(ss, waypoints, bc_type="clamped")
    if _overshooting_pieces(path, ss, waypoints, config).any():
        # A clamped cubic through unevenly spaced waypoints can swing far outside them: a door's state, timed as a
        # coordinate of Fetch's handle path, went 0.14 rad below its closed state where one step turned the slow
        # wrist far and the next barely (the hand drove the door into its stop, 274 N). First the cubic on evenly
        # spaced knots (the IK's waypoints are even steps of the handle); where that swings out too, cubic Hermite
        # pieces with PCHIP's slopes (zero at both ends, as clamped), which stay within each piece's waypoints but
        # bend sharply at them and are timed slower (Fetch's 12 cm retreat from geo_angled_rev_cabinet_00: 96 s).
        ss = np.linspace(0.0, 1.0, len(waypoints))
        path = toppra.SplineInterpolator(ss, waypoints, bc_type="clamped")
        if _overshooting_pieces(path, ss, waypoints, config).any():
            from scipy.interpolate import PchipInterpolator
            from toppra.simplepath import SimplePath

            slopes = PchipInterpolator(ss, waypoints, axis=0).derivative()(ss)
            slopes[[0, -1]] = 0.0
            path = SimplePath(ss, waypoints, slopes)
    constraints = [
        toppra.constraint.JointVelocityConstraint(np.column_stack([-v_max, v_max])),
        toppra.constraint.JointAccelerationConstraint(np.column_stack([-a_max, a_max])),
    ]
    grid = np.linspace(0.0, 1.0, max(config.min_gridpoints, config.grid_factor * len(waypoints)))
    algorithm = toppra.algorithm.TOPPRA(constraints, path, gridpoints=grid, parametrizer="ParametrizeConstAccel")
    timed = algorithm.compute_trajectory(0.0, 0.0)
    if timed is None:
        # A piece far shorter than its neighbours (a 0.1 mrad step before a 0.5 rad one, found by the property test)
        # leaves toppra's reachability analysis without a controllable set at the first gridpoint, on any
        # interpolation through it. Inner waypoints within a thousandth of the path's largest joint travel of the
        # last one kept are dropped (no robot resolves them) and the path is timed again; the ends stay exact.
        kept = _spread_waypoints(waypoints, 1e-3 * float(np.max(np.abs(waypoints - waypoints[0]))))
        if len(kept) < len(waypoints):
            return retime_path(kept, v_max, a_max, config)
    if timed is None:
        # Still none: a corner where every joint's PCHIP slope is zero (one joint done, the next starting, the first
        # having moved microradians: found by the property test) is a cusp without a controllable set. The path is
        # driven waypoint to waypoint, each a rest-to-rest motion timed by ruckig state to state: slower, never
        # outside the limits.
        log.debug("toppra: no parametrisation of a %d-waypoint path; rest-to-rest between its waypoints", len(waypoints))
        return _joined([point_to_point(a, b, v_max, a_max, config) for a, b in zip(waypoints[:-1], waypoints[1:])])
    duration = float(timed.duration)
    t_dense = np.linspace(0.0, duration, max(3, int(np.ceil(duration / config.check_dt)) + 1))
    use = limit_use(t_dense, _sample(timed, t_dense, 1), v_max, a_max)
    scale = max(1.0, use.velocity, np.sqrt(use.acceleration)) * (1.0 + config.limit_tolerance)
    if scale > 1.0 + 2 * config.limit_tolerance:
        log.debug("toppra output uses %.3f of v_max, %.3f of a_max: slowed by %.4f", use.velocity, use.acceleration, scale)
    n = int(np.ceil(duration * scale / config.dt))
    t = np.arange(n + 1) * config.dt
    tau = np.minimum(t / scale, duration)
    q = _sample(timed, tau)
    qd = _sample(timed, tau, 1) / scale
    q[-1], qd[-1] = waypoints[-1], 0.0
    return Trajectory(t, q, qd)


def _joined(parts: list[Trajectory]) -> Trajectory:
    """Rest-to-rest trajectories one after the other (each starts where the last ended, sampled at the same period)."""
    t, q, qd = [parts[0].t], [parts[0].q], [parts[0].qd]
    for part in parts[1:]:
        t.append(t[-1][-1] + part.t[1:])
        q.append(part.q[1:])
        qd.append(part.qd[1:])
    return Trajectory(np.concatenate(t), np.concatenate(q), np.concatenate(qd))


def point_to_point(
    q_start: npt.ArrayLike,
    q_goal: npt.ArrayLike,
    v_max: npt.ArrayLike,
    a_max: npt.ArrayLike,
    config: RetimeConfig = RetimeConfig(),
) -> Trajectory:
    """Time-synchronised, jerk-limited rest-to-rest motion between two joint states (ruckig, offline).

    Only the current and target states are given to ruckig (no intermediate waypoints).

    Args:
        q_start, q_goal: (n,) joint positions.
        v_max, a_max: (n,) limits; the jerk limit is ``jerk_per_acceleration * a_max``.

    Raises:
        PlanningError: ruckig rejects the request.
    """
    q_start = np.asarray(q_start, dtype=np.float64)
    q_goal = np.asarray(q_goal, dtype=np.float64)
    n = len(q_start)
    if np.max(np.abs(q_goal - q_start)) < 1e-9:
        return Trajectory(np.zeros(1), q_start[None].copy(), np.zeros((1, n)))
    inp = ruckig.InputParameter(n)
    inp.current_position = q_start.tolist()
    inp.current_velocity = [0.0] * n
    inp.current_acceleration = [0.0] * n
    inp.target_position = q_goal.tolist()
    inp.target_velocity = [0.0] * n
    inp.target_acceleration = [0.0] * n
    inp.max_velocity = np.asarray(v_max, dtype=np.float64).tolist()
    inp.max_acceleration = np.asarray(a_max, dtype=np.float64).tolist()
    inp.max_jerk = (config.jerk_per_acceleration * np.asarray(a_max, dtype=np.float64)).tolist()
    trajectory = ruckig.Trajectory(n)
    result = ruckig.Ruckig(n).calculate(inp, trajectory)
    if result not in (ruckig.Result.Working, ruckig.Result.Finished):
        raise PlanningError(f"ruckig: no trajectory between the two states ({result})")
    duration = float(trajectory.duration)
    steps = int(np.ceil(duration / config.dt))
    t = np.arange(steps + 1) * config.dt
    q = np.empty((len(t), n))
    qd = np.empty((len(t), n))
    for i, ti in enumerate(np.minimum(t, duration)):
        position, velocity, _ = trajectory.at_time(float(ti))
        q[i], qd[i] = position, velocity
    q[-1], qd[-1] = q_goal, 0.0
    return Trajectory(t, q, qd)


__all__ = ["LimitUse", "RetimeConfig", "Trajectory", "limit_use", "point_to_point", "retime_path"]
