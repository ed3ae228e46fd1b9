"""Where and how the gripper takes a handle: the grasp frame along the handle's path (tilted for reach,
rolled about the handle as the part turns), how deep the fingers go, how wide they open.

Pure geometry on the task and the robot's finger boxes; no simulation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from funrec.typed import FloatArray
from funrec_robot.grasp_frames import (
    T_world_grasp_canonical,
    T_world_grasp_path,
    grasp_free_axis,
    roll_to_hold,
    rotation_about_grasp_axis,
)
from funrec_robot.robot import RobotDescription
from funrec_robot.robot_geometry import RobotGeometry
from funrec_robot.task import ArticulationTask


@dataclass(frozen=True)
class GraspConfig:
    """Settings of the grasp."""

    fingertip_clearance: float = 0.012
    """Gap wanted between the fingertips and the part's front behind the handle, m."""
    min_fingertip_clearance: float = 0.004
    """Smallest such gap accepted when the handle stands too close to the front for the wanted one, m."""
    unknown_surface_offset: float = 0.02
    """Handle standoff from the front assumed when the task does not know it, m."""
    unknown_handle_width: float = 0.035
    """Thickness across the pads assumed for opening the gripper when the task does not know the handle's
    (a twin): the thickest bar or knob expected; the fingers then close until they stop on it, m."""
    pad_margin: float = 0.003
    """The contact point stays this far inside the finger pads' depth range, m."""
    touch_speed: float = 0.06
    """Speed at which the gap between the jaws closes over the widths a handle of unknown thickness may have
    (``unknown_handle_width`` down to closed), m/s: a guarded close that meets the handle slowly wherever it is.
    Closed in the usual half second, Spot's hinged jaw met the twins' 8 mm bars at 0.3 m/s, sank up to 13 mm
    into them before MuJoCo's soft contact pushed back, and wedged in the bar with 100-500 N (9 of 23 twin parts
    passed); at 4 or 6 cm/s it sinks at most 1.3-2.1 mm (of the 4 mm to the bar's middle) and the same 18
    pass. Stretch 3's light_dim_pri_drawer_00, whose drawer coasts after the release, ends within the 2 cm
    target at 6 and 10 cm/s and 2-3 mm beyond it at 3 and 4 cm/s and without the slow phase: a marginal part."""
    grip_margin: float = 0.015
    """Each finger opens this much wider than half the handle's thickness before closing on it, m."""
    grip_squeeze: float = 0.002
    """Each finger is commanded this far into the handle while holding it (a light squeeze), m."""
    fixed_jaw_clearance: float = 0.003
    """Gap between a fixed jaw and a bar handle as the hand comes onto it, m: the moving jaw then closes the handle
    onto the fixed one."""
    fixed_jaw_knob_clearance: float = 0.012
    """The same for a knob, m. Measured with Spot on the bench's three knob doors (peak handle force on the last
    approach): 58-91 N at 3 mm, 39-51 N at 8 mm, 7-44 N at 12 mm; bars pass at 3 mm and fail at 8 or 12 mm (a
    microwave 126 N, a cabinet door 148 N). Why a knob wants more room was not found."""
    release_gap: float = 0.005
    """On letting go each finger opens this far clear of the handle, m."""
    max_roll: float = float(np.deg2rad(45.0))
    """Largest turn of the handle between the pads about the grasp's free axis, rad."""
    tilts: tuple[float, ...] = (0.0, -0.2, 0.2, -0.35, 0.35, -0.5, 0.5, -0.7, 0.7, -0.9, 0.9, -1.1, 1.1)
    """Tilts of the grasp about the handle tried for reach (low and high handles), rad."""
    tilt_cost: float = 0.1
    """Preference for small tilts when ordering them, m/rad."""
    tilt_deadband: float = 0.35
    """Wrist targets within this height of the shoulder need no tilt, m."""
    palm_check_length: float = 0.15
    """A bar handle is taken to reach this far either side of the contact point when checking it clears the
    palm, m."""
    handle_radius: float = 0.006
    """Geoms of the part within this distance of the contact point are the handle (the gripper may touch
    them; it avoids the rest of the part), m."""
    fall_roll: float = float(np.pi / 2)
    """Turn of the gripper about a bar handle, from facing the part's front, by the state where the part is let
    go to fall (a drop-down door opened as far as the arm reaches): the fingers then point along the front
    towards the hinge, the door comes to rest across one finger, and the retreat slides the hand off the bar
    along the door, outwards, which neither lifts nor pushes it (friction there acts through the hinge), rad."""
    fall_roll_from: float = 0.5
    """Fraction of the path to that state after which the gripper starts turning towards ``fall_roll``."""
    fall_state: float | None = None
    """Set by the planner: the path state where the part is let go to fall (None: it is held to its target)."""


@dataclass(frozen=True)
class GraspCandidate:
    """One way of taking the handle, with its frames along the path."""

    tilt: float
    """Tilt about the handle, rad."""
    depth: float
    """Distance of the grasp frame before the contact point along the approach, m."""
    opening: float
    """Gripper command before closing."""
    holding: float
    """Gripper command while holding."""
    frames: FloatArray
    """(N, 4, 4) T_world_grasp along the path states."""
    max_roll: float | None = None
    """The roll limit ``frames`` were made with (``handle_frames``); None: ``GraspConfig.max_roll``."""
    offset: float = 0.0
    """Where the handle's centre sits along the grasp y, m: 0 between two moving jaws; with a fixed jaw, off it by
    ``GraspConfig.fixed_jaw_clearance`` (``jaw_offset``). The hand's targets are ``frames @ offset_frame(offset)``."""


PALM_DEPTH_STEP_M = 0.001
"""Step by which a bar that meets the palm is taken further out along the pads, m."""

FLIP = np.diag([-1.0, -1.0, 1.0, 1.0])
"""Half a turn about the grasp z: the same grasp for a symmetric parallel gripper."""


def tilt_axis(task: ArticulationTask) -> int:
    """Grasp axis (0 x, 1 y) of a static tilt: the more horizontal one, so that tilting pitches the approach
    up or down (for a horizontal bar its own axis; for a vertical bar or a knob on a vertical hinge, the other)."""
    R = T_world_grasp_canonical(task)[:3, :3]
    return int(np.argmin(np.abs(R[2, :2])))


def handle_across(task: ArticulationTask, tilt: float) -> float:
    """Extent of a handle of known thickness across the pads of a grasp tilted by ``tilt``, m: its thickness and,
    tilted, part of its depth along the approach (its thickness where the depth is not known)."""
    assert task.handle_width is not None
    depth = task.handle_width if task.handle_depth is None else task.handle_depth
    return float(task.handle_width * np.cos(tilt) + depth * abs(np.sin(tilt)))


def opening_commands(
    robot: RobotDescription, task: ArticulationTask, config: GraspConfig, tilt: float = 0.0
) -> tuple[float, float]:
    """Gripper commands before closing and while holding: each finger (a slide whose command is its
    position) half the handle's extent across the pads plus a margin from the middle (a tilted grasp sees
    part of the handle's depth), then half its thickness minus the squeeze. When the thickness is unknown the
    fingers open as for ``unknown_handle_width`` (not fully: open fingers sweep into the front and plinth
    below a low handle) and close fully, stopping on the handle."""
    gripper = robot.gripper
    low, high = sorted((gripper.closed, gripper.open))
    if task.handle_width is None:
        return float(np.clip(gripper.command(config.unknown_handle_width / 2 + config.grip_margin), low, high)), gripper.closed
    opening = float(np.clip(gripper.command(handle_across(task, tilt) / 2 + config.grip_margin), low, high))
    holding = float(np.clip(gripper.command(task.handle_width / 2 - config.grip_squeeze), low, high))
    return opening, holding


def guarded_close(robot: RobotDescription, task: ArticulationTask, config: GraspConfig) -> tuple[float, float] | None:
    """Where a close onto a handle of unknown thickness slows down, and how fast it then goes on to closed:
    (command of jaws ``unknown_handle_width`` apart, command units per second for ``touch_speed``); None when the
    task knows the thickness (the jaws close to it and meet it at rest)."""
    if task.handle_width is not None:
        return None
    gripper = robot.gripper
    low, high = sorted((gripper.closed, gripper.open))
    start = float(np.clip(gripper.command(config.unknown_handle_width / 2), low, high))
    return start, abs(gripper.command(config.touch_speed / 2) - gripper.closed)


def release_command(robot: RobotDescription, holding: float, config: GraspConfig) -> float:
    """Gripper command on letting go: ``release_gap`` (the robot's, else the config's) looser than holding, no wider. A grasp rolled against the
    part's front has a finger close to it; opening wide would push the part away."""
    gripper = robot.gripper
    low, high = sorted((gripper.closed, gripper.open))
    gap = config.release_gap if gripper.release_gap is None else gripper.release_gap
    looser = gripper.command(config.grip_squeeze + gap) - gripper.closed
    return float(np.clip(holding + looser, low, high))


def surface_offset(task: ArticulationTask, config: GraspConfig) -> float:
    """How far the handle's contact point stands in front of the part's front, m: the task's, or
    ``config.unknown_surface_offset`` when the twin does not say."""
    return task.surface_offset if task.surface_offset is not None else config.unknown_surface_offset


def grasp_depth(
    task: ArticulationTask, geometry: RobotGeometry, opening: float, tilt: float, config: GraspConfig,
    clear_palm: bool = False,
) -> float | None:
    """How far before the contact point the grasp frame sits so that every finger corner, with the gripper
    at ``opening`` and tilted by ``tilt`` about the contact point, stays ``fingertip_clearance`` in front of
    the part's front, keeping the contact ``pad_margin`` inside the pads; None if the gap would then be
    below ``min_fingertip_clearance``, or if a bar handle there meets the palm (with ``clear_palm``: unless taking
    it further out on the pads clears it)."""
    offset = surface_offset(task, config)
    corners = geometry.finger_corners.copy()
    # Fingers slide along the grasp y: move the corners from fully open to this opening.
    corners[:, 1] -= np.sign(corners[:, 1]) * max(finger_half_opening(geometry) - opening, 0.0)
    R = rotation_about_grasp_axis(tilt_axis(task), [tilt])[0]
    reach = float(np.max((corners @ R.T)[:, 2]))
    depth = min(
        max(0.0, (reach - offset + config.fingertip_clearance) / np.cos(tilt)),
        geometry.finger_depth_range[1] - config.pad_margin,
    )
    if offset - (reach - depth * np.cos(tilt)) < config.min_fingertip_clearance:
        return None
    # A thick bar taken that deep reaches back into the palm: it is taken further out on the pads instead, which
    # moves the fingertips further off the front (Meta-World's 51 mm drawer bar, 18 cm in front of the drawer, sat
    # in Spot's palm at every tilt and the drawer was refused, though the jaws open 75 mm).
    farthest = geometry.finger_depth_range[1] - config.pad_margin
    while _bar_meets_palm(task, geometry, depth, R, config):
        if not clear_palm:
            return None
        depth += PALM_DEPTH_STEP_M
        if depth > farthest:
            return None
    return depth


def _bar_meets_palm(task: ArticulationTask, geometry: RobotGeometry, depth: float, R: FloatArray, config: GraspConfig) -> bool:
    """Whether a bar handle, through the contact point along the grasp's free axis and tilted by ``R`` with the
    gripper, runs into the palm's boxes within ``palm_check_length`` either side (a steep pitch about the other
    axis lays the bar along the fingers, into the palm)."""
    if task.handle_axis_world is None or not len(geometry.palm_corners):
        return False
    direction = R.T @ np.eye(3)[grasp_free_axis(task)]
    s = np.linspace(-config.palm_check_length, config.palm_check_length, 121)
    points = np.array([0.0, 0.0, depth]) + s[:, None] * direction
    radius = (task.handle_width or 0.0) / 2 + config.pad_margin
    low, high = geometry.palm_corners.min(axis=0) - radius, geometry.palm_corners.max(axis=0) + radius
    return bool(np.any(np.all((points >= low) & (points <= high), axis=1)))


def finger_half_opening(geometry: RobotGeometry) -> float:
    """Half-opening of the open gripper: the smallest |y| of the finger corners (their inner faces), m."""
    return float(np.min(np.abs(geometry.finger_corners[:, 1])))


def about_contact(axis: int, angles: FloatArray, depth: float) -> FloatArray:
    """(N, 4, 4) rotations about a grasp axis through the contact point (``depth`` ahead along grasp z),
    to be applied on the right of grasp frames."""
    shift = np.eye(4)
    shift[2, 3] = depth
    R = np.tile(np.eye(4), (len(angles), 1, 1))
    R[:, :3, :3] = rotation_about_grasp_axis(axis, angles)
    return shift @ R @ np.linalg.inv(shift)


def knob_roll_limit(task: ArticulationTask, geometry: RobotGeometry, depth: float, config: GraspConfig) -> float:
    """Largest turn of a knob between the pads (about the grasp y through the contact point) that keeps every
    finger and palm corner ``min_fingertip_clearance`` in front of the part's front, up to ``max_roll``, rad.

    Held still while the part swings, the hand sees the front turn towards it about the knob: a wide jaw's
    corners beside the knob then meet the front (Spot's jaws 14-23 mm inside a door at 0.38 rad with the
    hand held still; the IK stopped 20 mm short). Beyond this turn the hand turns with the part."""
    if task.handle_axis_world is not None:
        return config.max_roll
    offset = surface_offset(task, config)
    corners = np.vstack([geometry.finger_corners, geometry.closed_finger_corners, geometry.palm_corners])
    lateral, ahead = np.abs(corners[:, 0]), corners[:, 2] - depth
    limit = 0.0
    for phi in np.linspace(0.0, config.max_roll, 46):
        if np.any(lateral * np.sin(phi) + ahead * np.cos(phi) > offset - config.min_fingertip_clearance):
            break
        limit = float(phi)
    return limit


def handle_frames(
    task: ArticulationTask, states: FloatArray, depth: float, tilt: float, config: GraspConfig,
    max_roll: float | None = None,
) -> FloatArray:
    """(N, 4, 4) grasp frames along the path.

    The grasp is first tilted by ``tilt`` about the handle (its free axis for a bar, its horizontal x for a
    knob) through the contact point, then along the path rolled about the free axis so that the gripper turns
    as little as the pads allow (a bar's total roll stays within ``max_roll``, a knob's within ``max_roll`` if
    given: ``knob_roll_limit``).
    """
    axis = grasp_free_axis(task)
    pitch_axis = tilt_axis(task)
    T0 = T_world_grasp_canonical(task, depth) @ about_contact(pitch_axis, np.array([tilt]), depth)[0]
    frames = T_world_grasp_path(task, states, T0)
    roll = roll_to_hold(frames[:, :3, :3], frames[0, :3, :3], axis, np.inf)
    spent = tilt if pitch_axis == axis else 0.0
    limit = config.max_roll if max_roll is None else max_roll
    roll = np.clip(roll, -limit - spent, limit - spent)
    if config.fall_state is not None and task.joint_type == "revolute" and task.handle_axis_world is not None:
        roll = _towards_fall_roll(task, states, T0, roll, spent, depth, config)
    return frames @ about_contact(axis, roll, depth)


def _towards_fall_roll(
    task: ArticulationTask, states: FloatArray, T0: FloatArray, roll: FloatArray, spent: float, depth: float, config: GraspConfig
) -> FloatArray:
    """(N,) the rolls about a bar turned, over the last part of the path up to ``config.fall_state``, to
    ``fall_roll`` from facing the front, towards the side whose fingers then point at the hinge."""
    assert config.fall_state is not None and task.pivot_world is not None
    axis = grasp_free_axis(task)
    T_fall = T_world_grasp_path(task, np.array([config.fall_state]), T0)[0]
    contact = T_fall[:3, 3] + depth * T_fall[:3, 2]
    toward_hinge = task.pivot_world - contact
    targets = [sign * config.fall_roll - spent for sign in (1.0, -1.0)]
    z = [(T_fall @ about_contact(axis, np.array([r]), depth)[0])[:3, 2] @ toward_hinge for r in targets]
    target = targets[int(np.argmax(z))]
    span = config.fall_state - float(states[0])
    progress = np.clip((np.asarray(states) - float(states[0])) / span, 0.0, 1.0) if abs(span) > 1e-9 else np.ones(len(states))
    weight = np.clip((progress - config.fall_roll_from) / (1.0 - config.fall_roll_from), 0.0, 1.0)
    return (1.0 - weight) * roll + weight * target


def jaw_offset(task: ArticulationTask, geometry: RobotGeometry, config: GraspConfig) -> float:
    """Where the handle's centre sits along the grasp y, m: 0 for a gripper whose jaws all move; with a fixed jaw
    (Spot's), as far from the grasp point as keeps the handle ``fixed_jaw_clearance`` (a knob
    ``fixed_jaw_knob_clearance``) off the jaw's inner face. A
    handle taken at the grasp point sat in Spot's fixed jaw by half its thickness (4-16 mm): the jaw struck it
    with 52-73 N on the last approach."""
    if geometry.fixed_jaw is None:
        return 0.0
    face, side = geometry.fixed_jaw
    width = task.handle_width
    if width is None:
        # A twin's bar is placed off the jaw by the thickness its mesh shows at most: placed as for the thickest
        # handle expected, Spot's fixed jaw stood 13-17 mm off the twins' 8-15 mm bars; the closing jaw then
        # pushed the hand (or the part) that far, left the bar at its fingertips, and the hand retreating from
        # the released bar hooked it with the jaws' teeth (the door dragged 0.16 rad past its target).
        width = config.unknown_handle_width if task.handle_width_max is None else min(task.handle_width_max, config.unknown_handle_width)
    clearance = config.fixed_jaw_clearance if task.handle_axis_world is not None else config.fixed_jaw_knob_clearance
    centre = face - side * (width / 2.0 + clearance)
    return centre if side * centre < 0.0 else 0.0


def offset_frame(offset: float) -> FloatArray:
    """(4, 4) the hand's target relative to the handle frame for a handle ``offset`` along the grasp y."""
    T = np.eye(4)
    T[1, 3] = -offset
    return T


def offset_along_approach(T_world_grasp: FloatArray, distance: float) -> FloatArray:
    """(4, 4) the grasp frame moved back by ``distance`` (m) against its approach (z)."""
    T = T_world_grasp.copy()
    T[:3, 3] -= distance * T[:3, 2]
    return T


def graspable_tilts(
    robot: RobotDescription, task: ArticulationTask, geometry: RobotGeometry, config: GraspConfig
) -> list[tuple[float, float, float, float]]:
    """(tilt, opening command, holding command, depth) of the tilts at which the open jaws are wider than the handle
    and the fingers take it clear of the part's front and the palm (``grasp_depth``), in ``config.tilts`` order. Only
    when no tilt does is a thick bar taken further out on the pads, clear of the palm (near the fingertips: a
    weaker grasp, and at 0.35 rad on a microwave's bar Spot's jaw struck it with 65 N where its usual grasp took 40 N)."""
    out = _graspable_tilts(robot, task, geometry, config, False)
    return out if out else _graspable_tilts(robot, task, geometry, config, True)


def _graspable_tilts(
    robot: RobotDescription, task: ArticulationTask, geometry: RobotGeometry, config: GraspConfig, clear_palm: bool
) -> list[tuple[float, float, float, float]]:
    out = []
    gripper = robot.gripper
    if _too_thick(robot, task):
        return out
    for tilt in config.tilts:
        if task.handle_width is not None and handle_across(task, tilt) > gripper.open_gap:
            continue  # a handle wider across the pads than the jaws open cannot be taken
        opening, holding = opening_commands(robot, task, config, tilt)
        depth = grasp_depth(task, geometry, opening, tilt, config, clear_palm)
        if depth is not None:
            out.append((tilt, opening, holding, depth))
    return out


def _too_thick(robot: RobotDescription, task: ArticulationTask) -> bool:
    """A handle of unknown thickness that is at least wider than the open jaws at every tilt (a round bar)."""
    return task.handle_width is None and task.handle_width_min is not None and task.handle_width_min > robot.gripper.open_gap


def ungraspable_reason(robot: RobotDescription, task: ArticulationTask, config: GraspConfig) -> str:
    """Why ``graspable_tilts`` finds no tilt, naming the dimension that fails: the handle's extent across the
    pads at its narrowest tilt against the jaws' open gap, or, where it fits, the palm and the part's front."""
    if task.handle_width is None:
        if _too_thick(robot, task):
            return (f"its bar is at least {1000.0 * task.handle_width_min:.0f} mm thick at any tilt (a round bar fitted "
                    f"to the part's mesh), wider than the jaws open ({1000.0 * robot.gripper.open_gap:.0f} mm)")
        return "its bar meets the palm, or the fingertips meet the part's front"
    gap, width = 1000.0 * robot.gripper.open_gap, 1000.0 * task.handle_width
    narrowest = 1000.0 * min(handle_across(task, tilt) for tilt in config.tilts)
    if narrowest <= gap:
        return (f"its bar ({width:.0f} mm thick) fits between the jaws ({gap:.0f} mm open), but wherever it does it "
                "meets the palm or the fingertips meet the part's front")
    tilted = "" if narrowest >= width else f" and {narrowest:.0f} mm across the pads at its narrowest tilt"
    return f"its bar is {width:.0f} mm thick{tilted}, wider than the jaws open ({gap:.0f} mm)"


def grasp_candidates(
    robot: RobotDescription,
    task: ArticulationTask,
    states: FloatArray,
    geometry: RobotGeometry,
    r_max: float,
    config: GraspConfig,
) -> list[GraspCandidate]:
    """Grasps to try, best first: untilted unless the wrist targets would sit farther above or below the
    shoulder than ``tilt_deadband``; tilts whose fingers cannot clear the part's front, or that put a wrist
    target beyond ``r_max`` (m) above or below the shoulder, are left out."""
    scored = []
    for tilt, opening, holding, depth in graspable_tilts(robot, task, geometry, config):
        max_roll = knob_roll_limit(task, geometry, depth, config)
        frames = handle_frames(task, states, depth, tilt, config, max_roll)
        wrist = frames[:, :3, 3] - frames[:, :3, 2] * geometry.wrist_to_grasp
        rise = float(np.max(np.abs(wrist[:, 2] - geometry.p_base_shoulder[2])))
        if rise < r_max:
            score = max(rise - config.tilt_deadband, 0.0) + config.tilt_cost * abs(tilt)
            scored.append((score, GraspCandidate(
                tilt, depth, opening, holding, frames, max_roll=max_roll, offset=jaw_offset(task, geometry, config)
            )))
    scored.sort(key=lambda item: item[0])
    return [candidate for _, candidate in scored]


__all__ = [
    "FLIP",
    "GraspCandidate",
    "GraspConfig",
    "about_contact",
    "finger_half_opening",
    "grasp_candidates",
    "grasp_depth",
    "guarded_close",
    "surface_offset",
    "graspable_tilts",
    "handle_across",
    "handle_frames",
    "jaw_offset",
    "knob_roll_limit",
    "offset_along_approach",
    "offset_frame",
    "opening_commands",
    "release_command",
    "tilt_axis",
    "ungraspable_reason",
]
