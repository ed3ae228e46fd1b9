"""The robot configurations of one interaction by whole-body IK: approach (with a via pose when the direct
joint motion collides), the handle path (refined until the joint interpolation stays on it), the retreat.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace

import mujoco
import numpy as np
import numpy.typing as npt

from funrec.errors import PlanningError
from funrec.typed import FloatArray
from funrec_robot.budget import TimeLimitSpent
from funrec_robot.feasibility import (
    GravityOverload,
    dynamic_limits,
    first_collision,
    gravity_overload,
    holding_force,
    joint_loads,
    path_collision,
    release_sweep_depth,
)
from funrec_robot.grasp import (
    FLIP,
    GraspCandidate,
    handle_frames,
    offset_along_approach,
    offset_frame,
    release_command,
    surface_offset,
)
from funrec_robot.ik import IKResult, WholeBodyIK
from funrec_robot.plan_config import PlanConfig
from funrec_robot.retime import Trajectory, point_to_point
from funrec_robot.robot import RobotDescription
from funrec_robot.scene import floor_geoms, geoms_near, hull_approximated, part_geoms
from funrec_robot.task import ArticulationTask
from funrec_robot.trajopt import BasePlacement

log = logging.getLogger(__name__)


class RetreatTooShort(PlanningError):
    """The handle path is planned, but the arm cannot back the gripper off the handle at its end: base placement
    left the arm no room along the approach there (``plan._search`` then places the base again with room for it)."""


class DeepInPart(PlanningError):
    """Every way round that reached the handle path of a part whose weight presses on the hand at its end leaves a
    finger in the scene there: the shallowest such solution, kept for when no other attempt does better."""

    def __init__(self, message: str, solution: dict, depth: float) -> None:
        super().__init__(message)
        self.solution, self.depth = solution, depth


class PathNotReached(PlanningError):
    """The whole-body IK lost the handle part-way along its path (``plan._search`` may let a part that gravity
    carries on to its target go before there, as where the arm's reach ends)."""

    def __init__(self, message: str, state: float) -> None:
        super().__init__(message)
        self.state = state
        """The first path state not reached, rad or m."""


def _base_q(robot: RobotDescription, pose: FloatArray) -> FloatArray:
    """Base joint positions (robot.base_motions order) for a base pose (x, y, yaw)."""
    return np.array([pose[{"x": 0, "y": 1, "yaw": 2}[m]] for m in robot.base_motions])


def stop_position(k: npt.ArrayLike, n: int, bases: int) -> FloatArray:
    """Where the base is between its stops at (fractional) path state ``k`` of ``n``, in stops (0 at the first,
    ``bases - 1`` at the last; outside that range it stands at the nearest): stop b serves the samples around
    position b. Its inverse, the path state at which the base stands at stop b: ``(b + 0.5) n / bases - 0.5``."""
    return (np.asarray(k, dtype=np.float64) + 0.5) * bases / n - 0.5


def posture_along(robot: RobotDescription, placement: BasePlacement, n: int) -> FloatArray:
    """(n, nq) posture references: home arm, base interpolated between the planned stops (:func:`stop_position`)."""
    B = len(placement.poses)
    position = stop_position(np.arange(n), n, B)
    posture = np.tile(robot.q_home, (n, 1))
    base = np.array([_base_q(robot, p) for p in placement.poses])
    nb = len(robot.base_joints)
    for j in range(nb):
        posture[:, j] = np.interp(position, np.arange(B), base[:, j])
    return posture


def _reached(e_pos: float, e_rot: float, config: PlanConfig) -> bool:
    return e_pos <= config.track_position_tolerance and e_rot <= config.track_orientation_tolerance


def _sideways(robot: RobotDescription, q_placed: FloatArray, q: FloatArray) -> float:
    """How far a differential drive's base at ``q`` lies across the line of its heading at ``q_placed``, m (0 for a
    base that does not turn: its x and y are its own)."""
    if robot.drive != "differential" or set(robot.base_motions) != {"x", "y", "yaw"}:
        return 0.0
    k = {m: i for i, m in enumerate(robot.base_motions)}
    yaw = float(q_placed[k["yaw"]])
    return abs(-np.sin(yaw) * float(q[k["x"]] - q_placed[k["x"]]) + np.cos(yaw) * float(q[k["y"]] - q_placed[k["y"]]))


def _from_grasp(robot: RobotDescription, posture: FloatArray, q_grasp: FloatArray) -> FloatArray:
    """(N, nq) posture references along the handle path whose base starts where the grasp left it and reaches the
    planned stops by the path's end: the base's offset from its planned pose at the grasp fades linearly along the
    path. Pulled to the planned pose at the path's first target instead, the base of Fetch, which the approach had
    left 19 cm off it, swept back 9 cm and its shoulder 0.22 rad round while the door turned 0.02 rad (the hand
    held on the twin's handle, pressing on the true one: shoulder pan beyond its effort limit, 152 N on the handle,
    person_sleeve_rev_cabinet_00)."""
    nb = len(robot.base_joints)
    offset = np.asarray(q_grasp[:nb], dtype=np.float64) - posture[0, :nb]
    for k, motion in enumerate(robot.base_motions):
        if motion == "yaw":
            offset[k] = float(np.angle(np.exp(1j * offset[k])))
    out = posture.copy()
    out[:, :nb] += np.outer(np.linspace(1.0, 0.0, len(posture)), offset)
    return out


def whole_body_configurations(
    robot: RobotDescription,
    model: mujoco.MjModel,
    joint: int,
    task: ArticulationTask,
    grasp: GraspCandidate,
    states: FloatArray,
    placement: BasePlacement,
    target_state: float,
    fingertip_depth: float,
    config: PlanConfig,
    unload: bool = False,
    rest_state: float | None = None,
) -> dict:
    """Whole-body IK for approach, grasp, handle path and retreat from a base placement; with ``unload``, the
    arm's gravity load is lowered through its null space at every IK waypoint (IKConfig.gravity_cost). A part let
    go to fall comes to rest at ``rest_state`` (None: it stays where the hand lets go): the retreat keeps clear of it
    there.

    Raises:
        GravityOverload: a joint must hold more than PlanConfig.gravity_effort_share of its effort limit.
        PlanningError: an IK target is missed or the approach runs into the scene.

    Returns a dict: grasp, flip, path (N, 4, 4 grasp frames used), states (N,), configs {approach:
    [q_start, (via,) q_pre, q_grasp], path: (N, nq), retreat, retreat_path: (K, nq) from the path's end to
    retreat along the approach}, tracked (IKResult), placement.
    """
    frames, depth = grasp.frames, grasp.depth
    start_state = float(states[0])
    data = mujoco.MjData(model)
    data.qpos[model.jnt_qposadr[joint]] = start_state
    mujoco.mj_kinematics(model, data)
    contact = frames[0, :3, 3] + depth * frames[0, :3, 2]
    radius = config.grasp.handle_radius
    if hull_approximated(model, joint):
        # A twin's part collides as convex pieces of its fused mesh, and the pieces round the handle bridge it to
        # the front behind (on the r16 twins the fingers stood 2-20 mm inside pieces whose boxes lay 14-27 mm from
        # the contact point, and the IK missed doors at 1.2-1.4 rad by 12-24 mm). The gripper may touch the
        # pieces as far from the contact point as the front: the grasp keeps the fingertips off the front itself.
        radius += surface_offset(task, config.grasp)
    handle = geoms_near(model, data, part_geoms(model, joint), contact, radius)
    base_points = np.column_stack([placement.poses[:, :2], np.full(len(placement.poses), 0.5)])
    ik = WholeBodyIK(robot, model, joint, np.vstack([frames[:, :3, 3], base_points]), handle, config.ik,
                     freeze_base=robot.drive == "differential")
    posture = posture_along(robot, placement, len(states))
    q_start = posture[0].copy()
    opening = grasp.opening

    scored = []
    # The hand's poses are solved with a differential drive free to roll along its heading (as along the handle
    # path): a telescoping arm reaches sideways, and its base's roll is what moves the hand along the front. For such
    # an arm (``IKConfig.hold_line``), a pre-grasp pose whose base ended off the line of its placed heading is solved
    # again with the base where it was placed (turning on the spot only), kept if reached: from home, rolling back
    # and forth while it turned, Stretch 3's base shifted 4.8 cm sideways towards a drawer (as a car parks), the
    # telescope then had 4.8 cm less to draw in than placed, and the IK missed the drawer's last centimetres by 6-16
    # mm (5 twins).
    for flip in (False, True):
        # The hand's targets: the handle frames, off the handle along the closing axis for a fixed jaw.
        path = (frames @ FLIP if flip else frames) @ offset_frame(grasp.offset)
        T_pre = offset_along_approach(path[0], config.pregrasp_distance)
        q_pre, e_pos, e_rot = ik.solve(T_pre, q_start, posture[0], start_state, opening, unload=unload, rolling=True)
        sideways = _sideways(robot, q_start, q_pre)
        if config.ik.hold_line and sideways > config.track_position_tolerance and _reached(e_pos, e_rot, config):
            q_held, e_held, r_held = ik.solve(T_pre, q_start, posture[0], start_state, opening, unload=unload, rolling=False)
            if _reached(e_held, r_held, config):
                q_pre, e_pos, e_rot = q_held, e_held, r_held
        score = e_pos + 0.1 * e_rot + 0.01 * float(np.linalg.norm(q_pre - q_start))
        scored.append((score, flip, path, q_pre, e_pos, e_rot))
    scored.sort(key=lambda item: item[0])
    errors: list[PlanningError] = []
    # A part whose weight presses on the hand where the path ends (a drop-down door at its stop) runs ahead of the
    # compliant hand and presses its front onto a finger that lies in it: Spot's hinged jaw, 3.5 mm inside
    # rev_oven_00_r3's door at the stop in the plan, lay 12 mm inside it in the check and the release met 107 N.
    # There both ways round are tried, and the one lying shallower in the scene (the part's front) kept; if both
    # lie in it, the caller tries its other base stops and grasps first (``DeepInPart``).
    loaded = _presses_on_hand(robot, model, joint, task, float(states[-1]), config)
    kept: tuple[float, dict] | None = None
    for rank, (_, flip, path, q_pre, e_pos, e_rot) in enumerate(scored):
        if rank > 0 and (e_pos > config.track_position_tolerance or e_rot > config.track_orientation_tolerance):
            break  # the other way round does not even reach the pre-grasp pose
        args = (robot, model, ik, task, grasp, states, placement, target_state, fingertip_depth, config, unload, flip, path,
                q_start, q_pre, e_pos, e_rot, posture, set(handle.tolist()), rest_state)
        straightened: list[bool] = []
        solution = _attempt(args, straightened, errors)
        if solution is None and straightened:
            # The straight approach ends in another grasp configuration than the joint move, and the handle path from
            # there may fail where it succeeded from the joint move's (TIAGo on dark_rev_glass_wall_00 missed it by
            # 5.2 mm at 0.646 rad, and the search spent its budget): then the joint move, as before.
            solution = _attempt(args, None, errors)
        if solution is None:
            continue
        if not loaded:
            return solution
        depth = _depth_at_stop(model, ik, solution, target_state, set(handle.tolist()))
        if kept is None or depth < kept[0]:
            kept = (depth, solution)
        if depth == 0.0:
            break
    if kept is not None and kept[0] > 0.0:
        raise DeepInPart(
            f"whole-body IK: holding part '{task.part}' at {target_state:.3f} {task.unit}, whose weight presses on the "
            f"hand, a finger lies {1000 * kept[0]:.1f} mm inside the scene", kept[1], kept[0])
    if kept is not None:
        return kept[1]
    for exc in errors[1:]:
        log.debug("the other way round: %s", exc)
    raise errors[0]


def _attempt(args: tuple, straightened: list[bool] | None, errors: list[PlanningError]) -> dict | None:
    """:func:`_from_pregrasp`, or None with its error appended to ``errors`` (a gravity overload too: the caller
    tries other postures if both ways fail)."""
    try:
        return _from_pregrasp(*args, straightened)
    except TimeLimitSpent:
        raise
    except PlanningError as exc:
        errors.append(exc)
        return None


def _presses_on_hand(robot: RobotDescription, model: mujoco.MjModel, joint: int, task: ArticulationTask, state: float,
                     config: PlanConfig) -> bool:
    """Whether holding the part still at ``state`` takes more than the robot's rest force on a finger
    (``gripper.fall_rest_force``, else the planner's): the same bound the planner lets a falling part go by."""
    return _weight_on_hand(model, joint, task, state) > robot.gripper.rest_force(config.fall_rest_force)


def _weight_on_hand(model: mujoco.MjModel, joint: int, task: ArticulationTask, state: float) -> float:
    """The force, N, that holding the part still at ``state`` by its handle takes against its weight and spring."""
    if task.joint_type == "revolute" and task.pivot_world is not None:
        force = holding_force(model, joint, np.array([state]), task.p_world_contact, task.axis_world, task.pivot_world)
        return float(np.linalg.norm(force[0]))
    return abs(float(joint_loads(model, joint, np.array([state]))[0]))


def _depth_at_stop(model: mujoco.MjModel, ik: WholeBodyIK, solution: dict, target_state: float, handle: set[int]) -> float:
    """How deep the robot lies in the scene, the handle and the floor aside, holding at the end of the handle path, m."""
    scene = np.flatnonzero(~np.isin(model.geom_bodyid, ik.indices.bodies))
    floor = set(floor_geoms(model, scene).tolist())
    holding = np.array([solution["grasp"].holding])
    return float(release_sweep_depth(model, ik, solution["configs"]["path"][-1], target_state, holding, handle, floor)[0][0])


def _from_pregrasp(
    robot: RobotDescription, model: mujoco.MjModel, ik: WholeBodyIK, task: ArticulationTask, grasp: GraspCandidate,
    states: FloatArray, placement: BasePlacement, target_state: float, fingertip_depth: float, config: PlanConfig,
    unload: bool, flip: bool, path: FloatArray, q_start: FloatArray, q_pre: FloatArray, e_pos: float, e_rot: float,
    posture: FloatArray, handle: set[int], rest_state: float | None, straightened: list[bool] | None,
) -> dict:
    """The rest of :func:`whole_body_configurations` for one way round of the gripper (``flip``) from its
    pre-grasp solution: grasp, approach (with a via pose if needed), handle path, retreat. With ``straightened`` (a
    list), a final approach whose joint move strays is solved straight (:func:`_straight_approach`), and True is
    appended to the list when it was; with None, the joint move is kept."""
    depth = grasp.depth
    start_state = float(states[0])
    opening, holding = grasp.opening, grasp.holding
    _require(e_pos, e_rot, config, "pre-grasp pose", start_state, task)
    q_grasp, e_pos, e_rot = ik.solve(path[0], q_pre, posture[0], start_state, opening, unload=unload, rolling=True)
    _require(e_pos, e_rot, config, "grasp pose", start_state, task)

    # Up to the pre-grasp pose nothing of the scene may be touched, the handle included (a swing through it
    # pushes the part before the grasp); only the last, slow move along the approach reaches it.
    allowed: set[int] = set()
    scene = np.flatnonzero(~np.isin(model.geom_bodyid, ik.indices.bodies))
    floor = set(floor_geoms(model, scene).tolist())
    approach = [q_start, q_pre, q_grasp]
    hit = first_collision(model, ik, _approach_samples(robot, model, q_start, q_pre, config), start_state, opening, allowed, floor)
    if hit is not None:
        T_via = offset_along_approach(path[0], config.via_distance)
        q_via, e_pos, e_rot = ik.solve(T_via, q_start, posture[0], start_state, opening, rolling=True)
        # The via pose only leads the hand around an obstacle, in free space: it need not be met to the
        # millimetre, nor in orientation (what it must be, collision-free, is checked below).
        _require(e_pos, e_rot, config, "approach via pose", start_state, task, (config.via_position_tolerance, np.pi))
        approach = [q_start, q_via, q_pre, q_grasp]
        hit = _first_hit(robot, model, ik, approach[:-1], start_state, opening, floor, config)
        if hit is not None:
            # The joint move from a hand held high to a low via swings the hand out through the furniture above
            # the handle (funrec_mm from home to a drawer at 0.40 m under another at 0.69 m: the hand 7 cm beyond
            # the upper drawer's front at 0.8 m high, reseed-8 plain_pri_drawer_01; the same on reseed-4
            # pri_drawer_04 and person_partial_pri_drawer_00). Then the hand goes to the via along a straight line,
            # through IK poses short moves apart, each move too short to swing far off it.
            line = _line_to(ik, q_start, T_via, posture[0], start_state, opening, config)
            if line is None or _first_hit(robot, model, ik, [q_start, *line, q_pre], start_state, opening, floor, config) is not None:
                raise PlanningError(f"approach of part '{task.part}': {hit[0]} runs into {hit[1]} (also through a via pose)")
            approach = [q_start, *line, q_pre, q_grasp]

    final_path = None
    if straightened is not None and _strays(ik, approach_move(robot, model, q_pre, q_grasp, config, config.final_approach_scale).q,
                                            path[0], config.pregrasp_distance, start_state, opening, config):
        straightened.append(True)
        final_path = _straight_approach(ik, task, path[0], q_pre, start_state, opening, unload, config)
        q_grasp = final_path[-1]
        approach[-1] = q_grasp

    give_up = (config.track_position_tolerance, config.track_orientation_tolerance)
    tracked = ik.track(path[1:], states[1:], q_grasp, _from_grasp(robot, posture[1:], q_grasp), holding, unload, give_up=give_up)
    worst = _worst_target(tracked.position_error, tracked.orientation_error, config)
    if not _tracked_all(tracked, len(states) - 1, config) and grasp.max_roll != 0.0 and task.joint_type == "revolute":
        # The hand held still while the part turns between the pads (up to ``max_roll``) meets the front turning
        # into its jaws: Spot's jaw hulls lay 14-16 mm inside cabinet doors at 0.3-0.9 rad and the IK, keeping them
        # out, stopped 20 mm short of the bar. Turning with the part keeps the hand as it was at the grasp, clear
        # of the front (as ``grasp.knob_roll_limit`` does for knobs); the grasp and the approach stay the same.
        turned = replace(grasp, frames=handle_frames(task, states, grasp.depth, grasp.tilt, config.grasp, 0.0), max_roll=0.0)
        path_turned = (turned.frames @ FLIP if flip else turned.frames) @ offset_frame(grasp.offset)
        again = ik.track(path_turned[1:], states[1:], q_grasp, _from_grasp(robot, posture[1:], q_grasp), holding, unload,
                         give_up=give_up)
        if _tracked_all(again, len(states) - 1, config):
            grasp, path, tracked = turned, path_turned, again
            worst = _worst_target(tracked.position_error, tracked.orientation_error, config)
    _require(tracked.position_error[worst], tracked.orientation_error[worst], config, "handle path", states[1 + worst], task,
             error=lambda message: PathNotReached(message, float(states[1 + worst])))
    q_path = np.vstack([q_grasp, tracked.q])
    states, path, q_path = _refine_path(ik, task, states, path, q_path, grasp, flip, holding, config)
    # The IK keeps the robot off the scene as the robot moves, not as the part moves into it: a fridge door swinging
    # towards Spot's body met a front leg that the base, trailing its planned stops, had left in its way (13 mm deep
    # in the plan's own kinematics; in the check the arm pushed the door with 1367 N, rev_fridge_01_r3).
    hit = path_collision(model, ik, q_path, states, holding, floor)
    if hit is not None:
        raise PlanningError(f"whole-body IK: along the handle path of part '{task.part}' the robot's "
                            f"{hit[1]} meets {hit[2]} at {hit[0]:.3f} {task.unit}")
    overload = gravity_overload(
        robot, model, ik, np.vstack([q_grasp, q_path]), np.r_[start_state, states], holding, config.gravity_effort_share,
        ik.part_joint,
    )
    if overload is not None:
        raise GravityOverload(
            f"part '{task.part}': at the planned grasp {overload[0]} must hold {overload[1]:.1f} against gravity "
            "(the robot's and the part's on the hand), "
            f"more than {config.gravity_effort_share:.0%} of its effort limit {overload[2]:.1f}",
            overload[0],
        )
    # The retreat only has to take the fingers off the handle: the IK's best effort is kept when it leaves
    # the handle ``min_retreat_clearance`` beyond the fingertips.
    released = release_command(robot, holding, config.grasp)
    if robot.gripper.release_sweep is not None:
        released = clear_release(robot, model, ik, task, q_path[-1], target_state, holding, released, handle, floor, config)
    T_end = ik.grasp_pose(q_path[-1], target_state, released)
    q_retreat = q_path[-1]
    # Every step is kept: the retreat is timed through them (``plan._timed``), so that the hand leaves the handle
    # straight back along the approach. Timed from its first configuration to its last alone, as one joint-space
    # move, Spot's hand swung 1.6 mm sideways into the opened jaw's side of a sliding door's bar, 5 mm away, as it
    # backed off, and knocked the door (15 kg on 1 N s/m) to 1.2 cm/s: it coasted 2 cm short of its target.
    retreat_path = [q_retreat]
    # A part let go to fall lies at its rest for all but the first moments of the (slowed) retreat: TIAGo's base,
    # solved against a dishwasher door still at the 0.19 rad it was let go at, rolled onto the door lying open.
    retreat_state = target_state if rest_state is None else rest_state
    steps = np.arange(1, int(np.ceil(config.retreat_distance / config.retreat_step)) + 1) * config.retreat_step
    for distance in np.minimum(steps, config.retreat_distance):
        T_retreat = offset_along_approach(path[-1], float(distance))
        q_next, e_pos, e_rot = ik.solve(T_retreat, q_retreat, q_retreat, retreat_state, released, rolling=True)
        if e_pos > config.track_position_tolerance or e_rot > config.track_orientation_tolerance:
            break
        q_retreat = q_next
        retreat_path.append(q_retreat)
    T_back = ik.grasp_pose(q_retreat, target_state, released)
    backed = float((T_end[:3, 3] - T_back[:3, 3]) @ T_end[:3, 2])
    needed = max(fingertip_depth - depth, 0.0) + config.min_retreat_clearance
    if backed < needed:
        raise RetreatTooShort(
            f"whole-body IK: retreat from part '{task.part}' at state {target_state:.3f} {task.unit} backs the gripper "
            f"off only {1000 * backed:.0f} mm ({1000 * needed:.0f} mm needed to clear the handle)"
        )
    return {
        "grasp": grasp,
        "flip": flip,
        "path": path @ np.linalg.inv(offset_frame(grasp.offset)),  # the handle's frames
        "states": states,
        "configs": {"approach": approach, "path": q_path, "retreat": q_retreat, "retreat_path": np.array(retreat_path),
                    "final_approach_path": final_path},
        "tracked": tracked,
        "placement": placement,
        "released": released,
        "tilt": 0.0,
    }


def _first_hit(robot: RobotDescription, model: mujoco.MjModel, ik: WholeBodyIK, waypoints: list[FloatArray], part_state: float,
               fingers: float, floor: set[int], config: PlanConfig) -> tuple[str, str] | None:
    """The first robot-scene contact (robot geom, scene geom) of the joint moves through ``waypoints`` (each (nq,)),
    the handle included, or None."""
    for q0, q1 in zip(waypoints[:-1], waypoints[1:]):
        hit = first_collision(model, ik, _approach_samples(robot, model, q0, q1, config), part_state, fingers, set(), floor)
        if hit is not None:
            return hit
    return None


def _line_to(ik: WholeBodyIK, q_start: FloatArray, T_to: FloatArray, q_posture: FloatArray, part_state: float,
             fingers: float, config: PlanConfig) -> list[FloatArray] | None:
    """IK solutions along the straight line from the grasp frame at ``q_start`` to ``T_to`` (4, 4), world frame,
    at most ``approach_line_step`` (m) apart, the orientation turned proportionally on the way (slerp); the last
    is ``T_to``'s. Each is solved from the one before, to ``via_position_tolerance`` (free space); None where one is
    missed."""
    from scipy.spatial.transform import Rotation, Slerp

    T_from = ik.grasp_pose(q_start, part_state, fingers)
    length = float(np.linalg.norm(T_to[:3, 3] - T_from[:3, 3]))
    fractions = np.linspace(0.0, 1.0, max(int(np.ceil(length / config.approach_line_step)), 1) + 1)[1:]
    turn = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([T_from[:3, :3], T_to[:3, :3]])))
    line, q = [], q_start
    for fraction, R in zip(fractions, turn(fractions).as_matrix()):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, (1.0 - fraction) * T_from[:3, 3] + fraction * T_to[:3, 3]
        q, e_pos, _ = ik.solve(T, q, q_posture, part_state, fingers, rolling=True)
        if e_pos > config.via_position_tolerance:
            return None
        line.append(q)
    return line


APPROACH_SAMPLES = 200
"""Most samples of the final approach's joint move :func:`_strays` looks at (it lasts 1-2 s on most robots, 0.01 s
a sample; Fetch's slow wrist made one of 52 s)."""


def _strays(ik: WholeBodyIK, q: FloatArray, T_grasp: FloatArray, distance: float, part_state: float, fingers: float,
            config: PlanConfig) -> bool:
    """Whether the hand, moved through the (K, nq) samples of the final approach's joint move, leaves the straight
    line of ``distance`` (m) along the approach onto ``T_grasp`` (4, 4) by more than the handle path's tracking
    tolerances (grasp point, hand orientation)."""
    p_grasp, z = T_grasp[:3, 3], T_grasp[:3, 2]
    for qk in q[np.unique(np.linspace(0, len(q) - 1, min(len(q), APPROACH_SAMPLES)).astype(int))]:
        T = ik.grasp_pose(qk, part_state, fingers)
        offset = T[:3, 3] - p_grasp
        along = float(np.clip(offset @ z, -distance, 0.0))
        off_line = float(np.linalg.norm(offset - along * z))
        cos = (np.trace(T_grasp[:3, :3].T @ T[:3, :3]) - 1.0) / 2.0
        if off_line > config.track_position_tolerance or np.arccos(np.clip(cos, -1.0, 1.0)) > config.track_orientation_tolerance:
            return True
    return False


def _straight_approach(ik: WholeBodyIK, task: ArticulationTask, T_grasp: FloatArray, q_pre: FloatArray,
                       part_state: float, fingers: float, unload: bool, config: PlanConfig) -> FloatArray:
    """(K, nq) IK steps of ``retreat_step`` from the pre-grasp pose straight onto the handle along the approach,
    each from the last; the last is the grasp configuration. Used where the joint move from the pre-grasp to the
    separately solved grasp configuration swings the hand off that line: Fetch's IK reached the grasp of a knob
    with the wrist rolled 1.1 rad from its pre-grasp roll, and the joint move between them swept a finger 16 mm
    through the knob (50-65 N on it for 12 s before the grasp, ``light_changing_rev_cabinet_00``).

    Raises:
        PlanningError: a step is not reached within the tracking tolerances.
    """
    q_path = [q_pre]
    steps = np.arange(1, int(np.ceil(config.pregrasp_distance / config.retreat_step)) + 1) * config.retreat_step
    for distance in np.maximum(config.pregrasp_distance - steps, 0.0):
        q_next, e_pos, e_rot = ik.solve(offset_along_approach(T_grasp, float(distance)), q_path[-1], q_path[-1],
                                        part_state, fingers, unload=unload, rolling=True)
        _require(e_pos, e_rot, config, f"straight approach ({1000 * distance:.0f} mm out)", part_state, task)
        q_path.append(q_next)
    return np.array(q_path)


def clear_release(
    robot: RobotDescription, model: mujoco.MjModel, ik: WholeBodyIK, task: ArticulationTask, q_end: FloatArray,
    target_state: float, holding: float, released: float, handle: set[int], floor: set[int], config: PlanConfig,
) -> float:
    """The gripper command to let go at: ``released``, or less open where opening that far on the handle at the
    end of the path would bring a finger more than the robot's ``gripper.release_sweep`` deeper into the part or
    the scene (the handle aside) than it lay while holding, which knocks the part off its target as the hand lets go,
    or any deeper into the scene but the part.
    Spot's hinged jaw, opened 7 mm clear of a microwave door's bar, swung 17 mm into the door and knocked it 0.11 rad
    back; opened 1 mm clear the door stayed (a sliding door's bar wants the full 5 mm to slide off).

    Raises:
        PlanningError: the fingers cannot even stop squeezing the handle (open ``GraspConfig.grip_squeeze``) within
            that depth; the gripper the other way round (``flip``) may.
    """
    limit = robot.gripper.release_sweep
    assert limit is not None
    commands = np.linspace(holding, released, config.release_sweep_samples)
    depths, names = release_sweep_depth(model, ik, q_end, target_state, commands, handle, floor)
    deeper = depths - depths[0] > limit
    # The rest of the scene does not yield as the part does: there the fingers may go no deeper than while holding.
    # Spot's jaw, opened on a sliding door's bar beside the wardrobe's fixed door, swept 6 mm into that door (within
    # the part's 8 mm): a collision (plain_pri_wardrobe_00_r3).
    part = set(part_geoms(model, ik.part_joint).tolist())
    rest, rest_names = release_sweep_depth(model, ik, q_end, target_state, commands, handle | part, floor)
    if (rest > rest[0]).any() and not deeper.any():
        depths, names, limit = rest, rest_names, 0.0
    deeper |= rest > rest[0]
    if not deeper.any():
        return released
    last = int(np.argmax(deeper)) - 1  # the last command before the first too deep
    loose = robot.gripper.command(config.grasp.grip_squeeze) - robot.gripper.closed
    if last < 0 or abs(commands[last] - holding) < abs(loose):
        raise PlanningError(
            f"release of part '{task.part}' at state {target_state:.3f} {task.unit}: the opening gripper sweeps "
            f"{names[0] if names else 'a finger'} {1000 * depths.max():.0f} mm into {names[1] if names else 'the scene'} "
            f"({1000 * depths[0]:.0f} mm while holding; {1000 * limit:.0f} mm more allowed) before it stops squeezing"
        )
    return float(commands[last])


def _refine_path(
    ik: WholeBodyIK,
    task: ArticulationTask,
    states: FloatArray,
    path: FloatArray,
    q_path: FloatArray,
    grasp: GraspCandidate,
    flip: bool,
    fingers: float,
    config: PlanConfig,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Insert IK waypoints where the joint-space segment between two waypoints strays from the handle path.

    The timed path interpolates joints between waypoints; where the arm reconfigures between two of them
    (near a joint limit, say) the grasp point in the middle can leave the handle's path by centimetres.
    Each pass checks the midpoint of every segment and solves a new waypoint where it is more than
    ``refine_tolerance`` off.
    """
    for _ in range(config.refine_passes):
        middle_q = (q_path[:-1] + q_path[1:]) / 2.0
        middle_s = (states[:-1] + states[1:]) / 2.0
        depth = grasp.depth
        expected = handle_frames(task, np.concatenate([[states[0]], middle_s]), depth, grasp.tilt, config.grasp, grasp.max_roll)[1:]
        if flip:
            expected = expected @ FLIP
        expected = expected @ offset_frame(grasp.offset)
        off = []
        for k, (q, s, T) in enumerate(zip(middle_q, middle_s, expected)):
            T_now = ik.grasp_pose(q, float(s), fingers)
            p_now = T_now[:3, 3] + depth * T_now[:3, 2]
            if np.linalg.norm(p_now - (T[:3, 3] + depth * T[:3, 2])) > config.refine_tolerance:
                off.append(k)
        if not off:
            break
        new_q = {k: ik.solve(expected[k], middle_q[k], middle_q[k], float(middle_s[k]), fingers, rolling=True)[0] for k in off}
        order = np.argsort(np.concatenate([np.arange(len(states)), np.array(off) + 0.5]), kind="stable")
        states = np.concatenate([states, middle_s[off]])[order]
        path = np.concatenate([path, expected[off]])[order]
        q_path = np.concatenate([q_path, np.array([new_q[k] for k in off])])[order]
    return states, path, q_path


def approach_move(robot: RobotDescription, model: mujoco.MjModel, q0: FloatArray, q1: FloatArray, config: PlanConfig,
                  scale: float) -> Trajectory:
    """One approach move as the plan times it: ruckig at ``scale`` of the dynamic limits (``plan._timed``), so that
    the collision test below sees the path the plan makes. Ruckig synchronises the joints in time, not along one
    line, so other limits take another path: tested at the robot's full limits, TIAGo's arm passed clear of a
    neighbouring door's knob and, as planned, swept through it (``plain_pri_drawer_02``, 1.15 s in)."""
    v, a = dynamic_limits(robot, model, config.effort_share_damping, config.effort_share_inertia)
    return point_to_point(q0, q1, scale * v, scale * a, config.retime)


def _approach_samples(robot: RobotDescription, model: mujoco.MjModel, q0: FloatArray, q1: FloatArray, config: PlanConfig) -> FloatArray:
    """Every sample of an approach move as the plan times it."""
    return approach_move(robot, model, q0, q1, config, config.approach_scale).q


def _tracked_all(tracked: IKResult, targets: int, config: PlanConfig) -> bool:
    """Whether the IK reached each of ``targets`` handle-path targets within the tracking tolerances."""
    return len(tracked.q) == targets and bool(np.all(tracked.position_error <= config.track_position_tolerance)) and bool(
        np.all(tracked.orientation_error <= config.track_orientation_tolerance))


def _worst_target(position_error: FloatArray, orientation_error: FloatArray, config: PlanConfig) -> int:
    """Index of the handle-path target to report: the first one beyond either tracking tolerance (where the
    tracking gave up: the last row of a short path), else the one with the largest sum of both residuals'
    ratios. By that sum alone, a target within both tolerances could outrank the missed one, and a short path
    then reached the refinement and raised IndexError (TIAGo on a twin of plain_pri_wardrobe_00)."""
    missed = np.flatnonzero((position_error > config.track_position_tolerance)
                            | (orientation_error > config.track_orientation_tolerance))
    if len(missed):
        return int(missed[0])
    return int(np.argmax(position_error / config.track_position_tolerance + orientation_error / config.track_orientation_tolerance))


def _require(
    e_pos: float, e_rot: float, config: PlanConfig, what: str, state: float, task: ArticulationTask,
    tolerances: tuple[float, float] | None = None, error: Callable[[str], PlanningError] = PlanningError,
) -> None:
    """Raise ``error`` unless the IK residuals are within ``tolerances`` (m, rad; default the tracking tolerances)."""
    position, orientation = tolerances or (config.track_position_tolerance, config.track_orientation_tolerance)
    if e_pos > position or e_rot > orientation:
        raise error(
            f"whole-body IK: {what} of part '{task.part}' at state {state:.3f} {task.unit} not reached: "
            f"{1000 * e_pos:.1f} mm, {np.rad2deg(e_rot):.1f} deg off (tolerance "
            f"{1000 * position:.0f} mm, {np.rad2deg(orientation):.0f} deg)"
        )


__all__ = ["DeepInPart", "PathNotReached", "approach_move", "posture_along", "stop_position", "whole_body_configurations"]
