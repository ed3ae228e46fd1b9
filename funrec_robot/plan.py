"""Plan one interaction: base placement (casadi), whole-body IK along the handle path (mink), timing (toppra,
ruckig). The only module that knows the order of the planning steps.

approach (ruckig: home -> pre-grasp -> grasp) | grasp (close the gripper) | actuate (toppra along the handle
path) | release (open the gripper) | retreat (ruckig back along the approach).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import mujoco
import numpy as np

from funrec.errors import PlanningError
from funrec.typed import FloatArray
from funrec_robot.budget import TimeLimitSpent, check_time_limit, plan_time_limit
from funrec_robot.errors import Refusal
from funrec_robot.feasibility import (
    GravityOverload,
    dynamic_limits,
    falls_to,
    first_blocked_state,
    hand_capacity,
    holding_force,
    holding_load,
    joint_loads,
    resting_state,
)
from funrec_robot.ghosts import part_ghosts, range_states, without_geoms
from funrec_robot.grasp import grasp_candidates, graspable_tilts, guarded_close, release_command, ungraspable_reason
from funrec_robot.grasp_frames import T_world_grasp_canonical, grasp_free_axis
from funrec_robot.plan_config import PlanConfig
from funrec_robot.plan_file import Plan, Segment, sha256_file
from funrec_robot.reach import (
    FLOOR_CHECK_ROOM,
    along_bar_to_lift,
    floor_reach_gap,
    handle_height,
    level_bar_ends,
    lifted,
    reach_refusal,
)
from funrec_robot.retime import Trajectory, point_to_point, retime_path
from funrec_robot.robot import RobotDescription, load_robot
from funrec_robot.robot_geometry import RobotGeometry, measure_robot
from funrec_robot.scene import (
    Polygon,
    bodies_geoms,
    hull_approximated,
    part_geoms,
    part_joint,
    part_sweep_footprint,
    part_travel,
    polygon_from_points,
    robot_bodies,
    static_footprint,
)
from funrec_robot.sim_model import build_mujoco_model
from funrec_robot.task import ArticulationTask, path_states, resolve_target
from funrec_robot.task_bounds import check_task_bounds
from funrec_robot.task_sources import load_task, locate_scene
from funrec_robot.trajopt import BasePlacement, PlacementError, PlacementProblem, place_base
from funrec_robot.whole_body import (
    DeepInPart,
    PathNotReached,
    RetreatTooShort,
    approach_move,
    stop_position,
    whole_body_configurations,
)

log = logging.getLogger(__name__)


def _per_joint(task: ArticulationTask, revolute: float, prismatic: float) -> float:
    """The setting for the task's joint type: ``revolute`` (rad) or ``prismatic`` (m)."""
    return revolute if task.joint_type == "revolute" else prismatic


REACH_CAP_FRACTION = 0.75
"""When 'open' / 'close' is capped at the arm's reach, the wrist stays within this fraction of the reach limit
above or below the shoulder: at the limit itself the whole-body IK misses the handle by ~9 cm on the bench's
drop-down doors (the arm is stretched out sideways as well as down)."""

PLANNER_VERSION = "funrec_robot.plan/1"
"""Written into every plan's provenance."""


def _placement_problem(
    robot: RobotDescription,
    model: mujoco.MjModel,
    joint: int,
    geometry: RobotGeometry,
    frames: FloatArray,
    states: FloatArray,
    bases: int,
    config: PlanConfig,
    falls_to: float | None = None,
    retreat: float = 0.0,
) -> PlacementProblem:
    """Base placement for the handle path's grasp ``frames`` at ``states`` from ``bases`` stops; with ``retreat``
    (m), the last stop also keeps the wrist in reach that far back along the approach from the path's end, where
    the retreat must take it to clear the handle."""
    wrist = frames[:, :3, 3] - frames[:, :3, 2] * geometry.wrist_to_grasp
    stretch = np.minimum((np.arange(len(states)) * bases) // len(states), bases - 1)
    targets, serving = wrist, stretch
    if retreat > 0.0:
        # Only after a retreat fell short (``_search``): the full retreat distance, not just the clearance the retreat
        # needs (54 mm for Stretch 3 on mw_drawer_00: its IK's base rolled off the stop and backed off 10-49 mm), and
        # not for every plan (Stretch's 1-stop placements of cabinet doors then missed the door by 5 mm: 2-3 times
        # the search).
        targets = np.vstack([wrist, wrist[-1] - frames[-1, :3, 2] * retreat])
        serving = np.r_[stretch, bases - 1]
    circles = geometry.base_circles + geometry.arm_circles
    z_band = (min(c.z_band[0] for c in circles), max(c.z_band[1] for c in circles))
    exclude = np.concatenate([bodies_geoms(model, robot_bodies(model)), part_geoms(model, joint)])
    static = static_footprint(model, exclude, z_band, wrist[:, :2].mean(axis=0), config.footprint_radius,
                              standing=hull_approximated(model, joint))
    fall = None
    if falls_to is not None:
        # A part let go to fall sweeps on to where it comes to rest, which a twin knows only from the
        # demonstration: the last stop, where the base stands meanwhile, also keeps clear of ``fall_sweep_margin``
        # beyond.
        direction = 1.0 if falls_to >= states[-1] else -1.0
        fall = np.linspace(states[-1], falls_to + direction * config.fall_sweep_margin, 8)
    sweeps, passing = _sweep_windows(model, joint, states, bases, z_band, config.placement.clearance, fall)
    stretch_sweep = []
    for b in range(bases):
        mine = states[(stretch == b) | (stretch == b + 1)]
        sampled = mine[:: max(1, len(mine) // 12)].tolist() + [mine[-1]]
        if fall is not None and b == bases - 1:
            sampled += fall.tolist()
        stretch_sweep.append(part_sweep_footprint(model, joint, sampled, z_band))
    free = tuple(motion in robot.base_motions for motion in ("x", "y", "yaw"))
    return PlacementProblem(
        wrist_world=targets,
        stretch=serving,
        base_free=free,  # type: ignore[arg-type]
        base_fixed=np.zeros(3),
        p_base_shoulder=geometry.p_base_shoulder,
        reach=geometry.reach,
        base_circles=geometry.base_circles,
        arm_circles=geometry.arm_circles,
        static=static,
        sweep=tuple(sweeps),
        passing=passing,
        stretch_sweep=tuple(stretch_sweep),
        start_part=part_sweep_footprint(model, joint, [states[0]], z_band),
        reach_yaw=geometry.reach_yaw,
        reach_min=geometry.reach_min,
        rolling=robot.drive == "differential",
    )


def _stop_weights(k: float, n: int, bases: int) -> FloatArray:
    """(bases,) weights of the stops' poses in the base's pose at (fractional) path state ``k`` of ``n``: the
    interpolation of ``whole_body.posture_along``, whose references the IK follows."""
    position = min(max(float(stop_position(k, n, bases)), 0.0), bases - 1.0)
    w = np.zeros(bases)
    low = min(int(np.floor(position)), bases - 1)
    w[low] = 1.0 - (position - low)
    if position > low:
        w[low + 1] = position - low
    return w


def _merged(footprints: tuple[Polygon, ...]) -> tuple[Polygon, ...]:
    """One footprint for all of a part's: the hull of their vertices over their heights together. Over a window the
    part moves no further than the clearance, so the hull adds little to its pieces (a door's bar and the shelves on
    its back lie within its slab's hull but for the bar's standoff) and IPOPT sees one polygon per window instead of
    one per geom (a fridge door has five)."""
    if len(footprints) < 2:
        return footprints
    band = (min(p.z_band[0] for p in footprints), max(p.z_band[1] for p in footprints))
    return (polygon_from_points(footprints[0].name, np.vstack([p.vertices for p in footprints]), band),)


def _sweep_windows(
    model: mujoco.MjModel,
    joint: int,
    states: FloatArray,
    bases: int,
    z_band: tuple[float, float],
    step: float,
    after: FloatArray | None = None,
) -> tuple[tuple[tuple[Polygon, ...], ...], tuple[tuple[FloatArray, tuple[Polygon, ...]], ...]]:
    """What of the part's sweep each base pose must keep clear of: per stop, the footprints of the part while the
    base stands there (the last stop also over the states ``after`` the path: a part let go falling on); and
    (weights of the stops, footprints) for the base on its way between two stops.

    The base follows ``whole_body.posture_along``: path state k has the base at position (k + 0.5) B / n - 0.5
    between the stops (clamped to the first and last), so it stands at a stop only there and is on its way to the
    next while the part moves on. The path is cut at the stops and into windows in which no corner of the part
    travels further than ``step`` (the placement's clearance: a window asks the base to keep clear of at most that
    much more of the sweep than the part covers at any one instant); the base keeps clear of a window's swept
    footprint at both its ends and half-way (it moves on a straight line between stops). A stop keeps clear of the
    part over the windows it stands in or next to (one footprint per geom, as with one stop, where that is the
    whole sweep), not of its whole stretch: with one footprint per stop over its stretch and the next, the first of
    3 stops kept clear of two thirds of a fridge door's sweep, which in a room corner left no room (issue 14)."""
    n = len(states)
    index = np.arange(n, dtype=np.float64)
    travelled = np.r_[0.0, np.cumsum(part_travel(model, joint, states))]
    knots = np.clip((np.arange(bases) + 0.5) * n / bases - 0.5, 0.0, n - 1.0)
    cuts = np.unique(np.r_[0.0, knots, n - 1.0])

    def between(a: float, c: float) -> FloatArray:
        return np.r_[np.interp(a, index, states), states[(index > a) & (index < c)], np.interp(c, index, states)]

    spans = np.tile([np.inf, -np.inf], (bases, 1))  # path states (fractional) around each stop
    passing: list[tuple[FloatArray, tuple[Polygon, ...]]] = []
    for start, end in zip(cuts[:-1], cuts[1:]):
        length = float(np.interp(end, index, travelled) - np.interp(start, index, travelled))
        pieces = max(1, math.ceil(length / step - 1e-9))
        bounds = np.linspace(start, end, pieces + 1)
        if length > 0.0:
            bounds = np.interp(np.linspace(np.interp(start, index, travelled), np.interp(end, index, travelled), pieces + 1),
                               travelled, index)
            bounds[0], bounds[-1] = start, end
        for a, c in zip(bounds[:-1], bounds[1:]):
            footprint: tuple[Polygon, ...] | None = None
            for k in (a, 0.5 * (a + c), c):
                w = _stop_weights(k, n, bases)
                at = np.flatnonzero(w > 1.0 - 1e-9)
                if len(at):
                    spans[at[0]] = min(spans[at[0], 0], a), max(spans[at[0], 1], c)
                else:
                    footprint = footprint or _merged(part_sweep_footprint(model, joint, between(a, c), z_band))
                    if footprint:  # nothing of the part at the base's height (a wall cabinet): nothing to keep clear of
                        passing.append((w, footprint))
    spans[:, 0] = np.minimum(spans[:, 0], knots)  # one state only (the reach check): the part where it is
    spans[:, 1] = np.maximum(spans[:, 1], knots)
    sweeps = [between(*span) for span in spans]
    sweeps[-1] = np.r_[sweeps[-1], () if after is None else after]
    return tuple(part_sweep_footprint(model, joint, swept, z_band) for swept in sweeps), tuple(passing)


def _demo_states(task: ArticulationTask, start: float, config: PlanConfig) -> FloatArray:
    """(N,) path states of the demonstration from ``start``: its states in order, thinned so that consecutive
    ones differ by at least ``demo_min_step`` (the hand's pauses and jitter are not path waypoints)."""
    step = _per_joint(task, config.demo_min_step_rad, config.demo_min_step_m)
    kept = [start]
    for state in task.demo_states:
        if abs(state - kept[-1]) >= step:
            kept.append(float(state))
    if abs(task.demo_states[-1] - kept[-1]) > 1e-9:
        kept[-1] = float(task.demo_states[-1])
    if len(kept) < 2:
        raise PlanningError(f"part '{task.part}': the demonstration does not move the part from {start:.3f} {task.unit}")
    return np.array(kept)


def _reachable_prefix(states: FloatArray, reachable: Callable[[FloatArray], bool]) -> int:
    """Largest k such that ``reachable(states[:k])`` (0 if not even two states are): bisection, since a path
    that is reachable stays reachable when shortened."""
    low, high = 1, len(states)  # reachable(states[:low]) is assumed, states[:high] is known not to be
    while high - low > 1:
        check_time_limit("the handle path (arm's reach)")
        mid = (low + high) // 2
        low, high = (mid, high) if reachable(states[:mid]) else (low, mid)
    return low if low >= 2 else 0


def _slowed(trajectory: Trajectory, factor: float, dt: float) -> Trajectory:
    """The same motion ``factor`` times slower (velocities divided by it), resampled every ``dt``."""
    t = np.arange(int(np.ceil(trajectory.duration * factor / dt)) + 1) * dt
    tau = np.minimum(t / factor, trajectory.duration)
    q = np.column_stack([np.interp(tau, trajectory.t, trajectory.q[:, j]) for j in range(trajectory.q.shape[1])])
    qd = np.column_stack([np.interp(tau, trajectory.t, trajectory.qd[:, j]) for j in range(trajectory.qd.shape[1])]) / factor
    return Trajectory(t, q, qd)


def _concatenate(pieces: list[tuple[str, Trajectory, FloatArray, FloatArray]], dt: float) -> tuple[FloatArray, ...]:
    """Join trajectories that meet at rest; returns t, q, qd, gripper, part_state and the segments."""
    t_all, q_all, qd_all, g_all, s_all, segments = [], [], [], [], [], []
    t0, index = 0.0, 0
    for label, traj, gripper, part in pieces:
        skip = 1 if t_all else 0  # the first sample repeats the previous piece's last one
        n = len(traj.t) - skip
        if n <= 0:
            continue
        t_all.append(t0 + traj.t[skip:])
        q_all.append(traj.q[skip:])
        qd_all.append(traj.qd[skip:])
        g_all.append(gripper[skip:])
        s_all.append(part[skip:])
        start = max(index - 1, 0) if skip else index
        index += n
        segments.append((label, start, index - 1))
        t0 = float(t_all[-1][-1])
    t = np.round(np.round(np.concatenate(t_all) / dt) * dt, 9)
    return t, np.vstack(q_all), np.vstack(qd_all), np.concatenate(g_all), np.concatenate(s_all), segments  # type: ignore[return-value]


def _hold(q: FloatArray, seconds: float, dt: float) -> Trajectory:
    n = max(1, int(round(seconds / dt)))
    t = np.arange(n + 1) * dt
    return Trajectory(t, np.tile(q, (n + 1, 1)), np.zeros((n + 1, len(q))))


def _gripper_move(
    q: FloatArray, start: float, end: float, config: PlanConfig, hold_before: float = 0.0, duration: float | None = None,
    touch: tuple[float, float] | None = None,
) -> tuple[Trajectory, FloatArray]:
    """The robot holding still while the gripper command waits ``hold_before``, goes from start to end
    (ruckig, 1 DoF) in about ``duration`` (default ``config.gripper_time``), then settles. A guarded close,
    ``touch`` = (command, speed in command units per second): the ruckig move stops at that command and the
    command then goes on to ``end`` at that constant speed."""
    first = end if touch is None else touch[0]
    span = abs(first - start)
    v = max(span, 1e-6) / (0.6 * (config.gripper_time if duration is None else duration))
    values = point_to_point([start], [first], [v], [4.0 * v], config.retime).q[:, 0]
    if touch is not None:
        steps = max(1, int(np.ceil(abs(end - first) / (touch[1] * config.retime.dt))))
        values = np.concatenate([values, np.linspace(first, end, steps + 1)[1:]])
    settle = int(round(config.grasp_settle_time / config.retime.dt))
    wait = int(round(hold_before / config.retime.dt))
    values = np.concatenate([np.full(wait, start), values, np.full(settle, end)])
    return _hold(q, (len(values) - 1) * config.retime.dt, config.retime.dt), values


@dataclass(frozen=True)
class _HandlePath:
    """The states the handle is to be carried through, after the target was resolved and capped."""

    states: FloatArray
    """(N,) part states along the handle path, rad or m."""
    start_state: float
    """The part's state when the robot arrives."""
    target_state: float
    """Where the hand lets go."""
    final_state: float | None
    """Where the part comes to rest after release, if not where the hand lets go (a part let go to fall)."""
    demo: bool
    """The path is the demonstration's."""
    capped: tuple[float, str] | None
    """(state, scene geom) where the part first runs into the scene on the way, if it does."""
    reach_capped: dict | None
    """The state the arm's reach capped the target at, and the requested one (recorded in the plan)."""
    config: PlanConfig
    """The settings, with the grasp's fall state set for a part let go to fall."""
    candidates: list
    """Grasp candidates along ``states`` (``grasp.grasp_candidates``), best first."""
    placed: dict = field(default_factory=dict)
    """Base placements of the best candidate already made, by number of stops (a ``BasePlacement``, or the
    ``PlacementError`` it raised; ``_best_placements``): the search reuses them."""


def _requested_states(
    task: ArticulationTask, model: mujoco.MjModel, joint: int, target: str | float, start: float | None, config: PlanConfig,
    to_stop: bool = True,
) -> tuple[FloatArray, float, float, bool, tuple[float, str] | None]:
    """Path states from the start to the target, the target stopped short of the range ends (but, with ``to_stop``,
    for a part its weight carries to the end: there) and of where the part first runs into the scene; returns states,
    start, target, demo, and where it was blocked."""
    start_state = task.state_current if start is None else float(start)
    target_state = resolve_target(task, target)
    check_task_bounds(task, start_state, target_state)
    capped = None
    if isinstance(target, str) and target.strip().lower() in ("open", "close"):
        margin = _per_joint(task, config.end_margin_rad, config.end_margin_m)
        low, high = task.state_range
        step = _per_joint(task, config.free_range_step, config.free_range_step_m)
        blocked = first_blocked_state(model, joint, start_state, target_state, step)
        if blocked is not None:
            capped = blocked
            low, high = (max(low, blocked[0]), high) if blocked[0] < start_state else (low, min(high, blocked[0]))
        short = float(np.clip(target_state, low + margin, high - margin))
        # A part that its weight carries from there to its stop (a drop-down door) comes to rest at the stop: held
        # short of it, the hand is dragged there, turned about the bar by the door (Spot's jaw, opening, then swung
        # 14 mm into rev_oven_00_r3's panel). It is opened to the stop itself.
        if not to_stop or blocked is not None or not falls_to(model, joint, short, target_state, step):
            target_state = short
    if abs(target_state - start_state) < 1e-6:
        raise PlanningError(f"part '{task.part}' is already at the target state {target_state:.4g} {task.unit}")
    step = _per_joint(task, config.free_range_step, config.free_range_step_m)
    if falls_to(model, joint, target_state, start_state, step):
        # Gravity beats the joint's friction everywhere back to the start: let go at the target, the part returns
        # (a 5 kg sash on a frictionless slide, mw_window_01: every robot that lifted it saw it fall shut).
        load = float(np.abs(joint_loads(model, joint, np.array([target_state]))[0]))
        raise Refusal(
            f"part '{task.part}' does not stay at {target_state:.3f} {task.unit}: its weight ({load:.1f} "
            f"{'N m' if task.joint_type == 'revolute' else 'N'}, beyond its joint's friction) carries it back to "
            f"{start_state:.3f} {task.unit} once let go"
        )
    demo = isinstance(target, str) and target.strip().lower() == "demo"
    if demo:
        states = _demo_states(task, start_state, config)
    else:
        states = path_states(task, start_state, target_state, T_world_grasp_canonical(task))
    return states, start_state, target_state, demo, capped


def _handle_path(
    robot: RobotDescription,
    model: mujoco.MjModel,
    joint: int,
    task: ArticulationTask,
    geometry: RobotGeometry,
    target: str | float,
    start: float | None,
    config: PlanConfig,
) -> _HandlePath:
    """The handle path and its grasp candidates; 'open' / 'close' beyond the arm's reach are cut to where it
    reaches (a part gravity carries on from there is let go to fall).

    Raises:
        PlanningError: no grasp tilt keeps the handle path within the arm's vertical reach.
    """
    states, start_state, target_state, demo, capped = _requested_states(task, model, joint, target, start, config)
    r_max = geometry.reach * config.placement.r_max_fraction
    candidates = grasp_candidates(robot, task, states, geometry, r_max, config.grasp)
    if not candidates:
        short = _requested_states(task, model, joint, target, start, config, to_stop=False)
        if short[2] != target_state:
            # The stop lies beyond the arm's reach where ``end_margin`` short of it does not: the door is opened that
            # far, as before, not cut short at the reach far below and let go to fall (Spot, reseed-3
            # light_harsh_rev_dishwasher_00: cut at 0.58 rad, the door fell onto its wrist, 136 N).
            short_candidates = grasp_candidates(robot, task, short[0], geometry, r_max, config.grasp)
            if short_candidates:
                (states, start_state, target_state, demo, capped), candidates = short, short_candidates
    handle = _HandlePath(states, start_state, target_state, None, demo, capped, None, config, candidates)
    if not candidates and not demo and isinstance(target, str):
        # 'open' / 'close' ask for the whole range; a drop-down door's full range takes its handle below the
        # arm's reach. Open it as far as the arm reaches instead (recorded in the plan; a number is exact).
        r_cap = r_max * REACH_CAP_FRACTION
        reachable = _reachable_prefix(states, lambda prefix: bool(grasp_candidates(robot, task, prefix, geometry, r_cap, config.grasp)))
        if reachable >= 2:
            log.warning("part '%s': the arm reaches the handle only up to %.3f %s of %.3f; planning that far",
                        task.part, states[reachable - 1], task.unit, target_state)
            handle = _cut_short(robot, model, joint, task, geometry, handle, reachable)
    candidates, config = handle.candidates, handle.config
    if not candidates and not graspable_tilts(robot, task, geometry, config.grasp):
        raise Refusal(
            f"part '{task.part}': the gripper cannot take the handle at any tilt: {ungraspable_reason(robot, task, config.grasp)}"
        )
    if not candidates:
        raise Refusal(
            f"part '{task.part}': the handle path leaves the arm's vertical reach from the shoulder "
            f"({geometry.p_base_shoulder[2]:.2f} m high) whatever the grasp tilt"
        )
    return handle


def _cut_short(robot: RobotDescription, model: mujoco.MjModel, joint: int, task: ArticulationTask, geometry: RobotGeometry,
               handle: _HandlePath, reachable: int, by: str = "reach") -> _HandlePath:
    """The handle path cut to its first ``reachable`` states, as far as the arm reaches (recorded in the plan). A part
    that gravity carries on to the requested target (a drop-down door) is let go there and falls open: the plan's
    target stays the requested one, and the hand holds it no further than it may rest on a finger (``_held_prefix``)."""
    config, requested = handle.config, handle.target_state
    states = handle.states[:reachable]
    target_state, final_state = float(states[-1]), None
    reach_capped: dict = {"state": target_state, "requested": requested, "by": by}
    step = _per_joint(task, config.free_range_step, config.free_range_step_m)
    if falls_to(model, joint, target_state, requested, step, not config.fall_ignores_friction):
        final_state = requested
        reach_capped["released_to_fall"] = True
        light = _held_prefix(robot, model, joint, task, geometry, states, config)
        if light >= 2:
            states, target_state = states[:light], float(states[light - 1])
            reach_capped["state"] = target_state
        # The gripper turns on the bar to let the door go sideways off a finger (GraspConfig.fall_roll).
        config = replace(config, grasp=replace(config.grasp, fall_state=target_state))
    candidates = grasp_candidates(robot, task, states, geometry, geometry.reach * config.placement.r_max_fraction, config.grasp)
    return replace(handle, states=states, target_state=target_state, final_state=final_state, reach_capped=reach_capped,
                   config=config, candidates=candidates, placed={})


def _held_prefix(robot: RobotDescription, model: mujoco.MjModel, joint: int, task: ArticulationTask, geometry: RobotGeometry,
                 states: FloatArray, config: PlanConfig) -> int:
    """How many leading ``states`` a revolute part that is let go to fall may be held for: up to the first where its
    weight presses on the hand with more than ``fall_rest_force`` (the robot's, else the config's) or than the arm holds within
    ``gravity_effort_share`` of its joints' efforts (``hand_capacity``), or where a lift would hold more than that
    share of its effort limit (the weight above it, in every posture the same, and the part's pull on the hand).
    ``len(states)`` if none; 0 for a prismatic part."""
    if task.joint_type != "revolute" or task.pivot_world is None:
        return 0
    force = holding_force(model, joint, states, task.p_world_contact, task.axis_world, task.pivot_world)
    limit = min(robot.gripper.rest_force(config.fall_rest_force), hand_capacity(robot, model, config.gravity_effort_share))
    light = np.linalg.norm(force, axis=1) <= limit
    if geometry.lift_range is not None:
        lift = len(robot.base_joints)
        weight = float(holding_load(robot, model, robot.q_home[None])[0, lift])
        load = np.abs(weight + geometry.lift_sign * force[:, 2])
        light &= load <= config.gravity_effort_share * float(robot.effort_max[lift])
    return int(np.argmin(np.r_[light, False]))


def _floor_refusal(
    robot: RobotDescription, model: mujoco.MjModel, joint: int, task: ArticulationTask, geometry: RobotGeometry,
    handle: _HandlePath,
) -> str | None:
    """Why no base pose clear of the furniture brings the shoulder within reach of the handle's first wrist target
    at any grasp tilt (``reach.floor_reach_gap``), or None: a handle high over a counter the base cannot stand
    under. Checked only where every grasp leaves the wrist little horizontal room (a handle high or low)."""
    config = handle.config
    r_max = geometry.reach * config.placement.r_max_fraction
    # The IK keeps a lift, a slide, ``limit_margin_m`` inside its range.
    margin = config.ik.limit_margin_m
    lift_down, lift_up = (geometry.lift_range[0] + margin, geometry.lift_range[1] - margin) if geometry.lift_range else (0.0, 0.0)
    targets = []
    for candidate in handle.candidates:
        wrist = candidate.frames[0, :3, 3] - candidate.frames[0, :3, 2] * geometry.wrist_to_grasp
        # The shoulder as near the wrist's height as the planned lift puts it.
        shoulder_z = float(np.clip(wrist[2], geometry.p_base_shoulder[2] + lift_down, geometry.p_base_shoulder[2] + lift_up))
        if r_max**2 - (wrist[2] - shoulder_z) ** 2 >= (FLOOR_CHECK_ROOM * r_max) ** 2:
            return None
        targets.append((wrist, shoulder_z))
    if not targets:
        return None
    problem = _placement_problem(robot, model, joint, geometry, handle.candidates[0].frames[:1], handle.states[:1], 1, config)
    gaps = []
    for wrist, shoulder_z in targets:
        gap = floor_reach_gap(wrist, shoulder_z, geometry.p_base_shoulder[:2], geometry.base_circles,
                              problem.static + problem.start_part, r_max, config.placement.clearance)
        if gap is None:
            return None
        gaps.append(gap)
    lift = f" (its {robot.arm_joints[0]} {100 * margin:.0f} cm inside its limit)" if geometry.lift_range else ""
    return (
        f"part '{task.part}': handle at {handle_height(task):.2f} m over furniture the base cannot stand under: "
        f"wherever the base stands {100 * config.placement.clearance:.0f} cm clear of it, the wrist stays at least "
        f"{r_max + min(gaps):.3f} m from the shoulder{lift} for a reach of {r_max:.3f} m, at every grasp tilt"
    )


def _search(
    robot: RobotDescription,
    model: mujoco.MjModel,
    joint: int,
    task: ArticulationTask,
    geometry: RobotGeometry,
    handle: _HandlePath,
    cpu_started: float,
    stop_at_path_miss: float | None = None,
) -> dict:
    """Try base stops (1, 2, ...) and grasp tilts, cheapest first, until base placement and whole-body IK
    succeed or the CPU time budget is spent; a gravity overload moves on to the robot's next home posture,
    then to unloading the arm, then to grasps that point the gripper down. With ``stop_at_path_miss`` (a path state),
    the first attempt whose IK loses the handle on the path beyond that state ends the search (``PathNotReached``).

    Returns ``whole_body_configurations``' solution.

    Raises:
        PlanningError: the error of the furthest step reached (IK beats base placement).
    """
    config, candidates, states = handle.config, handle.candidates, handle.states
    # A differential drive's stops lie on its line of travel (PlacementProblem.rolling): it rolls between them.
    max_stops = config.max_base_stops
    # Each stop serves at least one path state: a short path (a part barely opened, a twin's small range) with
    # more stops than states left a stop without states, and an IndexError reached the user.
    max_stops = min(max_stops, len(states))
    attempts = sorted(
        ((bases, rank) for bases in range(1, max_stops + 1) for rank in range(len(config.grasp.tilts))),
        key=lambda attempt: attempt[0] + 0.6 * attempt[1],
    )
    errors: list[tuple[int, PlanningError]] = []
    # (base stops, grasp rank, unload the arm, base placement to reuse, room for the retreat in the placement)
    pending: list[tuple[int, int, bool, BasePlacement | None, bool]] = [
        (bases, rank, False, None, False) for bases, rank in attempts if rank < len(candidates)
    ]
    postures = list(robot.q_postures)
    # The shallowest solution that left a finger in a weighted part's front (``DeepInPart``): the plan if no attempt
    # keeps clear of it.
    deep: DeepInPart | None = None
    # Attempts in a home posture left for the next one, unloading the arm through its null space instead, as
    # (home, attempt): tried once the others are spent.
    unload_in: list[tuple[FloatArray, tuple[int, int, bool, BasePlacement | None, bool]]] = []
    while (pending or unload_in) and time.process_time() - cpu_started < config.time_budget:
        check_time_limit("the search over base stops and grasps")
        if not pending:
            home, attempt = unload_in.pop(0)
            robot = replace(robot, q_home=home)
            pending.append(attempt)
        bases, rank, unload, placement, room = pending.pop(0)
        grasp = candidates[rank]
        known = handle.placed.get(bases) if rank == 0 and not room and placement is None else None
        if isinstance(known, PlacementError):
            errors.append((0, known))
            continue
        placement = known if placement is None else placement
        if placement is None:
            problem = _placement_problem(robot, model, joint, geometry, grasp.frames, states, bases, config, handle.final_state,
                                         config.retreat_distance if room else 0.0)
            try:
                placement = place_base(problem, config.placement)
            except TimeLimitSpent:
                raise
            except PlanningError as exc:
                errors.append((0, exc))
                continue
        try:
            return whole_body_configurations(robot, model, joint, task, grasp, states, placement, handle.target_state,
                                             geometry.fingertip_depth, config, unload, handle.final_state)
        except DeepInPart as exc:
            log.debug("part '%s', %d base stop(s), grasp %d: %s", task.part, bases, rank, exc)
            deep = exc if deep is None or exc.depth < deep.depth else deep
            continue
        except GravityOverload as exc:
            errors.append((1, exc))
            if geometry.lift_range is not None and exc.joint == robot.arm_joints[0]:
                # A lift holds the weight above it and the part's pull on the hand in every posture, grasp and
                # placement: nothing left to try (Stretch 3 tried them on plain_rev_oven_00's twin for the whole
                # 10 s budget, each at 63.0-63.9 N of its lift's 70 N).
                break
            if postures:  # the robot's next home posture may hold the gripper with less load on the wrist
                if not unload and config.ik.gravity_cost > 0.0:
                    # Fetch's elbow-out posture missed reseed-4 rev_wall_cabinet_01's pre-grasp by 0.7 m from every
                    # stop (the cabinet hangs high), after the home posture had reached it with the forearm roll
                    # 0.8 N m over its share: that reach, unloaded, is kept for last.
                    unload_in.append((robot.q_home, (bases, rank, True, placement, room)))
                robot = replace(robot, q_home=postures.pop(0))
                pending.insert(0, (bases, rank, False, None, room))
                continue
            if not unload and config.ik.gravity_cost > 0.0:  # no posture left: unload the arm through its null space
                pending.insert(0, (bases, rank, True, placement, room))
                continue
            # A wrist too weak to hold the gripper level: try the grasps that point it down most first.
            down = {r: float(candidates[r].frames[0, 2, 2]) for r in range(len(candidates))}
            pending.sort(key=lambda attempt: (down[attempt[1]], attempt[0]))
            continue
        except TimeLimitSpent:
            raise
        except PlanningError as exc:
            log.debug("part '%s', %d base stop(s), grasp %d: %s", task.part, bases, rank, exc)
            if stop_at_path_miss is not None and isinstance(exc, PathNotReached) and _beyond(exc.state, stop_at_path_miss, handle):
                raise
            errors.append((1, exc))
            if isinstance(exc, RetreatTooShort) and not room:
                # This stop and every later one placed with the retreat's end in reach: a telescoping arm drawn in to
                # the end of a drawer's pull cannot draw in further (Stretch 3 on mw_drawer_00 backed off 20 of 54 mm;
                # placed so, it planned from 3 stops).
                # (A placement kept for a retry, unloading the arm, stays as it is.)
                pending = [(bases, rank, unload, None, True)] + [(b, r, u, p, m or p is None) for b, r, u, p, m in pending]
            continue
    if deep is not None:
        return deep.solution
    if not errors:
        raise PlanningError(f"part '{task.part}': planning time budget exhausted")
    furthest = max(stage for stage, _ in errors)
    raise [exc for stage, exc in errors if stage == furthest][-1]


def _states_within(handle: _HandlePath, travel: float, side: str = "left") -> int:
    """How many of the handle path's states lie within ``travel`` (rad or m) of its start (``np.searchsorted``'s
    ``side`` at exactly ``travel``)."""
    return int(np.searchsorted(np.abs(handle.states - handle.start_state), travel, side=side))


def _beyond(state: float, mark: float, handle: _HandlePath) -> bool:
    """Whether a path state lies at or beyond ``mark`` on the way from the handle path's start to its target."""
    return (state - mark) * np.sign(handle.target_state - handle.start_state) >= 0.0


def _search_or_cut(
    robot: RobotDescription, model: mujoco.MjModel, joint: int, task: ArticulationTask, geometry: RobotGeometry,
    handle: _HandlePath, target: str | float, cpu_started: float,
) -> tuple[dict, _HandlePath]:
    """``_search``; for 'open' / 'close', the first attempt whose IK follows the handle over at least
    ``PlanConfig.path_cut_fraction`` of the way and then loses it cuts the path ``path_cut_back_rad`` (``_m``) before the state
    it missed, as the arm's reach does before the search (recorded in the plan: ``target_capped_by_reach``), and the
    search goes on with the shorter path. Not for a part that gravity would carry on from there (a drop-down door:
    let go part-way, it falls onto the hand). Fetch followed fridge doors to 1.54-1.72 of their 1.72-1.86 rad and missed the
    handle by 10-17 mm from every base stop and grasp until the 10 s budget was spent."""
    config, states = handle.config, handle.states
    if handle.demo or not isinstance(target, str) or handle.reach_capped is not None or len(states) < 3:
        return _search(robot, model, joint, task, geometry, handle, cpu_started), handle
    travel = handle.target_state - handle.start_state
    k_late = _states_within(handle, config.path_cut_fraction * abs(travel))
    step = _per_joint(task, config.free_range_step, config.free_range_step_m)
    if k_late >= len(states) - 1 or falls_to(model, joint, float(states[k_late]), handle.target_state, step, not config.fall_ignores_friction):
        return _search(robot, model, joint, task, geometry, handle, cpu_started), handle
    mark = float(states[k_late])
    try:
        return _search(robot, model, joint, task, geometry, handle, cpu_started, stop_at_path_miss=mark), handle
    except PathNotReached as exc:
        if not _beyond(exc.state, mark, handle):  # every attempt failed, the last one early on the path
            raise
        back = _per_joint(task, config.path_cut_back_rad, config.path_cut_back_m)
        kept = max(2, _states_within(handle, abs(exc.state - handle.start_state) - back, side="right"))
        shorter = _cut_short(robot, model, joint, task, geometry, handle, kept, "whole-body IK")
        if shorter.final_state is not None or not shorter.candidates or falls_to(model, joint, shorter.target_state, handle.start_state, step):
            # It would fall on, or back (a drop-down door closed part-way), once let go there.
            return _search(robot, model, joint, task, geometry, handle, cpu_started), handle
        log.warning("part '%s': the arm follows the handle only up to %.3f %s of %.3f; planning to %.3f %s",
                    task.part, exc.state, task.unit, handle.target_state, shorter.target_state, task.unit)
        return _search(robot, model, joint, task, geometry, shorter, cpu_started), shorter


def _best_placements(robot: RobotDescription, model: mujoco.MjModel, joint: int, geometry: RobotGeometry,
                     handle: _HandlePath) -> dict:
    """The base placements of the handle path's best grasp from 1, 2, ... stops up to the first that places (the
    search's first placements, made ahead of it), by number of stops: a ``BasePlacement`` or the ``PlacementError``."""
    config = handle.config
    placed: dict = {}
    for bases in range(1, min(config.max_base_stops, len(handle.states)) + 1):
        problem = _placement_problem(robot, model, joint, geometry, handle.candidates[0].frames, handle.states, bases, config,
                                     handle.final_state)
        try:
            placed[bases] = place_base(problem, config.placement)
        except PlacementError as exc:
            placed[bases] = exc
            continue
        break
    return placed


def _search_along_bar(
    robot: RobotDescription, model: mujoco.MjModel, joint: int, task: ArticulationTask, geometry: RobotGeometry,
    handle: _HandlePath, target: str | float, start: float | None, cpu_started: float,
) -> tuple[ArticulationTask, dict, _HandlePath]:
    """``_search_or_cut``; where no base placement serves a level bar taken at its contact point, the search again
    with the bar taken near either end (``reach.level_bar_ends``), within the same time budget. Returns the task as
    taken, the solution and the handle path.

    For a part let go to fall (a drop-down door), whose fall the base keeps clear of in front of it, the ends come
    first once no placement serves the best grasp at the contact point (the other grasps there last): Stretch 3
    spent 3-4 s failing to place every grasp at the centres of the reseed-3 ovens' bars. Elsewhere the contact point
    is searched in full first: a robot that places there plans as before.

    Raises:
        PlanningError: the search's failure at the contact point if every end fails at base placement too, else
            the last failure."""
    ends = level_bar_ends(task)
    if ends and handle.final_state is not None:
        handle = replace(handle, placed=_best_placements(robot, model, joint, geometry, handle))
    centre_first = handle.final_state is None or not ends or any(not isinstance(p, PlacementError) for p in handle.placed.values())
    error: PlanningError | None = None
    if centre_first:
        try:
            return task, *_search_or_cut(robot, model, joint, task, geometry, handle, target, cpu_started)
        except PlacementError as exc:
            error = exc
    for moved in ends:
        try:
            moved_handle = _handle_path(robot, model, joint, moved, geometry, target, start, handle.config)
            solution, moved_handle = _search_or_cut(robot, model, joint, moved, geometry, moved_handle, target, cpu_started)
        except (TimeLimitSpent, Refusal):
            raise
        except PlanningError as exc:
            if error is None or not isinstance(exc, PlacementError):
                error = exc
            continue
        log.info("part '%s': no base placement for the bar at its contact point; taken %.3f m along it", task.part,
                 float((moved.p_world_contact - task.p_world_contact) @ np.asarray(task.handle_axis_world)))
        return moved, solution, moved_handle
    if not centre_first:
        return task, *_search_or_cut(robot, model, joint, task, geometry, handle, target, cpu_started)
    assert error is not None
    raise error


def _timed(
    robot: RobotDescription, model: mujoco.MjModel, task: ArticulationTask, handle: _HandlePath, solution: dict
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, tuple[Segment, ...]]:
    """Time the solved configurations: approach (ruckig, slow at the end), grasp, actuate (toppra along the
    handle path), release, retreat; returns t, q, qd, gripper command, part state and the segments."""
    config = handle.config
    path, configs, states, grasp = solution["path"], solution["configs"], solution["states"], solution["grasp"]
    opening, holding = grasp.opening, grasp.holding
    start_state, target_state = handle.start_state, handle.target_state
    v, a = dynamic_limits(robot, model, config.effort_share_damping, config.effort_share_inertia)
    rc = config.retime
    moves = list(zip(configs["approach"][:-1], configs["approach"][1:]))
    check_time_limit("timing (approach)")
    approach = [approach_move(robot, model, q0, q1, config, config.approach_scale) for q0, q1 in moves[:-1]]
    approach.append(_hold(moves[-1][0], config.pregrasp_dwell, rc.dt))
    final_path = configs.get("final_approach_path")
    if final_path is None:
        approach.append(approach_move(robot, model, *moves[-1], config, config.final_approach_scale))
    else:  # IK steps straight onto the handle (``whole_body._straight_approach``), timed as the handle path is
        approach.append(retime_path(final_path, config.final_approach_scale * v, config.final_approach_scale * a, rc))
    # The part state rides along as an extra path coordinate limited to the handle's speed and acceleration.
    radius = 1.0
    if task.joint_type == "revolute":
        radius = max(float(np.linalg.norm(np.cross(task.axis_world, path[0, :3, 3] - task.pivot_world))), 0.05)
    check_time_limit("timing (handle path)")
    actuate = retime_path(
        np.column_stack([configs["path"], states]),
        np.concatenate([v, [config.handle_speed / radius]]),
        np.concatenate([a, [config.handle_acceleration / radius]]),
        rc,
    )
    if handle.demo and task.demo_times.size and actuate.duration < float(task.demo_times[-1] - task.demo_times[0]):
        actuate = _slowed(actuate, float(task.demo_times[-1] - task.demo_times[0]) / actuate.duration, rc.dt)
    q_path = configs["path"]
    check_time_limit("timing (retreat)")
    retreat_path = configs.get("retreat_path")
    if retreat_path is None or len(retreat_path) < 3:
        retreat_path = np.array([q_path[-1], configs["retreat"]])
    # At the shares of what holding the arm there leaves of each effort limit: at the end of a path the arm may
    # be loaded near its limits (Fetch's forearm roll held 27 of its 29.35 N m against its spring and gravity on
    # light_harsh_rev_wall_00, and a retreat at the full limits asked 33 N m).
    v_back, a_back = dynamic_limits(robot, model, config.effort_share_damping, config.effort_share_inertia,
                                    np.abs(holding_load(robot, model, retreat_path)).max(axis=0))
    if len(retreat_path) >= 3:
        # Along the IK's steps straight back from the handle, as the handle path is timed.
        retreat = retime_path(retreat_path, v_back, a_back, rc)
    else:
        retreat = point_to_point(retreat_path[0], retreat_path[-1], v_back, a_back, rc)
    if handle.final_state is not None:
        # The released part rests on the open fingers until they have slid out from under it.
        scale = config.falling_retreat_scale if robot.gripper.fall_retreat_scale is None else robot.gripper.fall_retreat_scale
        retreat = _slowed(retreat, 1.0 / scale, rc.dt)
    end_state = target_state if handle.final_state is None else handle.final_state
    close_hold, close_cmd = _gripper_move(q_path[0], opening, holding, config, touch=guarded_close(robot, task, config.grasp))
    released = solution.get("released", release_command(robot, holding, config.grasp))
    open_hold, open_cmd = _gripper_move(q_path[-1], holding, released, config, config.release_hold_time,
                                        robot.gripper.release_time)

    def constant(traj: Trajectory, value: float) -> FloatArray:
        return np.full(len(traj.t), value)

    pieces = [("approach", piece, constant(piece, opening), constant(piece, start_state)) for piece in approach]
    pieces += [
        ("grasp", close_hold, close_cmd, constant(close_hold, start_state)),
        ("actuate", Trajectory(actuate.t, actuate.q[:, :-1], actuate.qd[:, :-1]), constant(actuate, holding), actuate.q[:, -1]),
        ("release", open_hold, open_cmd, constant(open_hold, target_state)),
        ("retreat", retreat, constant(retreat, released), constant(retreat, end_state)),
    ]
    t, q, qd, gripper, part_state, raw_segments = _concatenate(pieces, rc.dt)
    return t, q, qd, gripper, part_state, _merge_segments(raw_segments, t)


def _provenance(
    robot: RobotDescription,
    scene_xml: str | Path,
    task: ArticulationTask,
    target: str | float,
    handle: _HandlePath,
    solution: dict,
    timings: dict[str, float],
    cpu_started: float,
) -> dict:
    """What a plan records of how it was made: inputs and their hashes, the caps on its target, the grasp,
    the base stops, IK residuals, timings and the settings."""
    grasp, configs, tracked, placement = solution["grasp"], solution["configs"], solution["tracked"], solution["placement"]
    capped = handle.capped
    return {
        "planner": PLANNER_VERSION,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "robot_file": str(robot.yaml_path),
        "robot_sha256": sha256_file(robot.yaml_path),
        "robot_model_sha256": sha256_file(robot.model_path),
        "scene_file": str(scene_xml),
        "scene_sha256": sha256_file(scene_xml),
        "task_source": task.source,
        "grasp_source": task.grasp_source,
        "task_files": {str(p): sha256_file(p) for p in task.source_files if Path(p).is_file()},
        "target": str(target),
        "target_blocked_at": None if capped is None else {"state": capped[0], "by": capped[1]},
        "target_capped_by_reach": handle.reach_capped,
        "grasp": {
            "depth_m": grasp.depth,
            "flip": bool(solution["flip"]),
            "tilt_rad": grasp.tilt,
            "opening": grasp.opening,
            "release_command": solution.get("released"),
            "approach_vias": len(configs["approach"]) - 3,
            "straight_approach": configs.get("final_approach_path") is not None,
            "handle_axis_world": None if task.handle_axis_world is None else np.round(task.handle_axis_world, 6).tolist(),
            "approach_world": np.round(task.approach_world, 6).tolist(),
        },
        "base_stops": len(placement.poses),
        "placement_clearance_m": round(placement.clearance, 4),
        "ik_max_position_error_m": float(np.max(tracked.position_error)),
        "ik_max_orientation_error_rad": float(np.max(tracked.orientation_error)),
        "timings_s": timings,
        "plan_time_s": round(sum(timings.values()), 4),
        "plan_cpu_time_s": round(time.process_time() - cpu_started, 4),
        "config": asdict(handle.config),
    }


def plan_interaction(
    robot: RobotDescription,
    scene_xml: str | Path,
    task: ArticulationTask,
    target: str | float = "open",
    start: float | None = None,
    config: PlanConfig = PlanConfig(),
    model: mujoco.MjModel | None = None,
) -> Plan:
    """Plan a mobile manipulator opening (or closing) one articulated part of a scene.

    The steps: the handle path (target resolved, capped at the scene and the arm's reach), the search over
    base stops and grasp tilts (base placement, whole-body IK), timing, provenance.

    Args:
        robot: the robot.
        scene_xml: MJCF scene the task is expressed in (its world frame is the task's).
        task: the part and its joint, grasp and range (see ``task_sources``).
        target: 'open', 'close', 'demo' or a joint state (rad or m).
        start: the part's state when the robot arrives; default ``task.state_current``.
        config: settings.
        model: ``build_mujoco_model(robot, scene_xml, textures=False)`` if already built.

    Returns:
        The timed plan, starting with the base at its first stop and the arm at home, gripper open.

    Raises:
        PlanningError: naming the step that failed (base placement, IK at a path state, timing).
    """
    limit = config.time_limit
    if isinstance(limit, bool) or not isinstance(limit, (int, float)) or not math.isfinite(limit) or limit <= 0.0:
        raise PlanningError(f"time limit {limit!r}: expected a finite number of seconds > 0")
    with plan_time_limit(float(limit)):
        return _plan_interaction(robot, scene_xml, task, target, start, config, model)


def _plan_interaction(robot: RobotDescription, scene_xml: str | Path, task: ArticulationTask, target: str | float,
                      start: float | None, config: PlanConfig, model: mujoco.MjModel | None) -> Plan:
    """:func:`plan_interaction` under its time limit."""
    clock = time.perf_counter()
    cpu_started = time.process_time()
    timings: dict[str, float] = {}

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[name] = round(now - clock, 4)
        clock = now

    model = build_mujoco_model(robot, scene_xml, textures=False) if model is None else model
    lap("model")
    joint = part_joint(model, task.part)
    geometry = measure_robot(robot)
    refusal = reach_refusal(robot, geometry, task)
    if refusal is not None:
        raise Refusal(f"part '{task.part}': {refusal}")
    # A twin's static scene may hold copies of the part (``ghosts``): the planner does not avoid them. A scene of
    # primitive geoms has none: a true scene's fixed wardrobe door 2 cm beside the sliding one counted as one, and
    # Spot's opening jaw swept into it (plain_pri_wardrobe_00_r3).
    ghosts = np.zeros(0, dtype=np.int64)
    if hull_approximated(model, joint):
        ghosts = part_ghosts(model, joint, range_states(model, joint, task.state_range), task.p_world_contact)
    ghost_names = [model.geom(int(g)).name for g in ghosts]
    if ghost_names:
        log.info("part '%s': %d static geom(s) lie inside the part within its range, not obstacles: %s",
                 task.part, len(ghost_names), ", ".join(ghost_names))
        model = without_geoms(model, ghosts)
    settled = None
    if start is None:
        # The part is planned from where it rests in the scene: a part overlapping the scene at its recorded state
        # is pushed out by the contacts before the robot arrives (the check starts it there too).
        rest = resting_state(model, joint, task.state_current, config.settle_time, config.settle_speed)
        tolerance = _per_joint(task, config.settle_tolerance_rad, config.settle_tolerance_m)
        if abs(rest - task.state_current) > tolerance:
            log.warning("part '%s' does not rest at %.4f %s in the scene: it settles at %.4f; planning from there",
                        task.part, task.state_current, task.unit, rest)
            start, settled = rest, {"from": task.state_current, "to": rest}
    if geometry.lift_range is not None and not robot.base_lift:
        # An upright bar is taken where the lift serves, then the torso or mast starts at that height; the IK moves it on.
        task = along_bar_to_lift(geometry, task, config.ik.limit_margin_m)
    if geometry.lift_range is not None:
        robot = lifted(robot, geometry, handle_height(task), config.ik.limit_margin_m)
        geometry = measure_robot(robot)
    if geometry.reach_min > 0.0 and robot.drive == "differential":
        # A telescoping arm reaches along a line the base's heading sets: a turn of the base swings it all. Its
        # base holds its planned heading as a holonomic base holds its pose, and rolls (Stretch 3 turned by up to
        # 2 rad as a door opened, drew its telescope in to the stop and missed the handle by 6-8 mm). An arm with
        # a shoulder that pans turns with its base cheaply (TIAGo follows a door round so).
        config = replace(config, ik=replace(config.ik, posture_cost_rolling_yaw=config.ik.posture_cost_base, hold_line=True))
    handle = _handle_path(robot, model, joint, task, geometry, target, start, config)
    refusal = _floor_refusal(robot, model, joint, task, geometry, handle)
    if refusal is not None:
        raise Refusal(refusal)
    lap("path")
    task, solution, handle = _search_along_bar(robot, model, joint, task, geometry, handle, target, start, cpu_started)
    lap("placement_ik")
    t, q, qd, gripper, part_state, segments = _timed(robot, model, task, handle, solution)
    lap("retime")
    path, grasp, placement = solution["path"], solution["grasp"], solution["placement"]
    return Plan(
        robot_name=robot.name,
        joint_names=robot.joint_names,
        gripper_joints=robot.gripper.joints,
        gripper_open=robot.gripper.open,
        gripper_closed=robot.gripper.closed,
        grasp_command=grasp.holding,
        t=t,
        q=q,
        qd=qd,
        gripper_command=gripper,
        part_state=part_state,
        segments=segments,
        part=task.part,
        joint_type=task.joint_type,
        axis_world=task.axis_world,
        pivot_world=task.pivot_world,
        state_range=task.state_range,
        start_state=handle.start_state,
        target_state=handle.target_state if handle.final_state is None else handle.final_state,
        T_world_grasp_start=path[0],
        p_world_grasp_target=path[-1, :3, 3] + grasp.depth * path[-1, :3, 2],
        grasp_free_axis=grasp_free_axis(task),
        base_poses=placement.poses,
        provenance=_provenance(robot, scene_xml, task, target, handle, solution, timings, cpu_started)
        | {"ghost_geoms": ghost_names, "start_settled": settled},
        release_from_grip=task.handle_width is None,
    )


def plan_scene(
    robot_path: str | Path,
    scene: str | Path,
    part: str | None = None,
    target: str | float = "open",
    start: float | None = None,
    config: PlanConfig = PlanConfig(),
) -> Plan:
    """Load a robot and a scene (MJCF file, gt/ or capture folder, or twin folder) and plan one interaction.

    Raises:
        PlanningError: see :func:`plan_interaction`; also an unknown robot, scene or part.
    """
    robot = load_robot(robot_path)
    source = locate_scene(scene)
    model = build_mujoco_model(robot, source.scene_xml, textures=False)
    task = load_task(source, part, model)
    return plan_interaction(robot, source.scene_xml, task, target, start, config, model=model)


def _merge_segments(raw: list[tuple[str, int, int]], t: FloatArray) -> tuple[Segment, ...]:
    merged: list[list] = []
    for label, start, end in raw:
        if merged and merged[-1][0] == label:
            merged[-1][2] = end
        else:
            merged.append([label, start, end])
    return tuple(Segment(label, start, end, float(t[start]), float(t[end])) for label, start, end in merged)


__all__ = ["PLANNER_VERSION", "PlanConfig", "plan_interaction", "plan_scene"]

