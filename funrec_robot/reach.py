"""Whether a robot can reach a part's handle at all, decided in microseconds before any optimisation, and
the lift height (torso, mast) the planner starts from.

The model is the one base placement uses (``robot_geometry``), taken at its most generous: the hand reaches
a handle at heights within the arm's full reach plus the wrist-to-grasp length of the shoulder (the gripper
may point down onto a low handle), and a lift moves the shoulder up and down within its range. A handle
outside that band cannot be reached whatever the optimisation does; it is refused with one sentence.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from funrec.typed import FloatArray
from funrec_robot.robot import RobotDescription
from funrec_robot.robot_geometry import Circle, RobotGeometry
from funrec_robot.scene import Polygon
from funrec_robot.task import ArticulationTask, T_world_part

LIFT_ABOVE_HANDLE_M = 0.1
"""A lift puts the shoulder this far above the handle (the arm pulls best from slightly above), m."""
LIFT_MARGIN_M = 0.01
"""... and stays this far inside the range the whole-body IK keeps a slide in (``IKConfig.limit_margin_m`` inside
the lift's limits): a lift started within that margin made the IK's QP infeasible from its first step, m."""


@dataclass(frozen=True)
class ReachBand:
    """Heights a robot's hand reaches a handle at, with the base on the floor."""

    low: float
    """Lowest handle height, m (not below the floor)."""
    high: float
    """Highest handle height, m."""
    shoulder: tuple[float, float]
    """Lowest and highest shoulder height (equal without a lift), m."""

    def sentence(self, robot: RobotDescription, height: float) -> str:
        """Why a handle at ``height`` is out of reach, in one sentence."""
        lift = ""
        if self.shoulder[1] > self.shoulder[0]:
            joint = robot.arm_joints[0]
            k = len(robot.base_joints)
            lift = f" with its {joint} at {robot.q_min[k]:.2f}-{robot.q_max[k]:.2f} m (shoulder at {self.shoulder[0]:.2f}-{self.shoulder[1]:.2f} m)"
        return f"handle at {height:.2f} m; {robot.name} reaches {self.low:.2f}-{self.high:.2f} m{lift}"


def reach_band(geometry: RobotGeometry) -> ReachBand:
    """The band of handle heights within the arm's reach plus the wrist-to-grasp length of the shoulder (for a
    telescoping arm, what its slide moves the wrist up or down, ``RobotGeometry.reach_up``, in place of its
    reach: a horizontal telescope raises nothing)."""
    z = float(geometry.p_base_shoulder[2])
    down, up = geometry.lift_range if geometry.lift_range is not None else (0.0, 0.0)
    r = (geometry.reach if geometry.reach_up is None else geometry.reach_up) + geometry.wrist_to_grasp
    return ReachBand(max(z + down - r, 0.0), z + up + r, (z + down, z + up))


def handle_height(task: ArticulationTask) -> float:
    """Height of the handle where the hand takes it (the part at its current state), m."""
    T = T_world_part(task, [task.state_current])[0]
    return float(T[2, :3] @ task.p_world_contact + T[2, 3])


def reach_refusal(robot: RobotDescription, geometry: RobotGeometry, task: ArticulationTask) -> str | None:
    """One sentence on why the robot cannot reach the task's handle, or None if it may."""
    band = reach_band(geometry)
    height = handle_height(task)
    if band.low <= height <= band.high:
        return None
    return band.sentence(robot, height)


FLOOR_GRID_M = 0.01
"""Spacing of the shoulder positions :func:`floor_reach_gap` tries, m."""
FLOOR_YAWS = 144
"""Base headings it tries at each (every 2.5 degrees)."""
FLOOR_BEYOND_M = 0.1
"""How far beyond the horizontal room it looks for the nearest clear base pose, m."""
FLOOR_CHECK_ROOM = 0.6
"""It runs only when every grasp's wrist lies so far above or below the shoulder that it leaves less than this
fraction of the reach horizontally (a handle high over a counter): elsewhere the furniture rarely keeps every base
pose out of reach, and the check's 0.3-0.6 s went into every plan of a short arm (Stretch's 0.45 m)."""


def floor_reach_gap(
    wrist: FloatArray,
    shoulder_z: float,
    p_base_shoulder_xy: FloatArray,
    circles: Sequence[Circle],
    footprints: Sequence[Polygon],
    r_max: float,
    clearance: float,
) -> float | None:
    """How far beyond ``r_max`` the wrist target stays from the shoulder wherever the base stands with its discs
    ``clearance`` clear of the footprints (the lower-bound distance base placement keeps them off by), m; None
    when some base pose may bring it within ``r_max``.

    Shoulder positions on a grid of ``FLOOR_GRID_M`` within the horizontal room ``r_max`` leaves above or below
    the shoulder, and ``FLOOR_YAWS`` headings about each: a pose counts as clear when every disc's centre lies
    ``clearance`` plus its radius from every footprint less what the grid's spacing and the heading's step can
    move it, so a clear pose between grid points is never missed (the answer is a lower bound).

    Args:
        wrist: (3,) wrist target, world, m.
        shoulder_z: height of the shoulder (the highest or lowest a lift puts it, towards the wrist), m.
        p_base_shoulder_xy: (2,) shoulder in the base frame, m.
        circles: discs covering the robot's base (base frame).
        footprints: floor footprints of the furniture.
        r_max: farthest the wrist may be from the shoulder, m.
        clearance: gap kept between a disc and a footprint, m.
    """
    dz = float(wrist[2] - shoulder_z)
    if r_max**2 - dz**2 < 0.0 or not circles:
        return None if r_max**2 >= dz**2 else float(abs(dz) - r_max)
    # The horizontal room r_max leaves, and FLOOR_BEYOND_M more to say how far beyond it the nearest clear pose is.
    room = float(np.sqrt(r_max**2 - dz**2)) + FLOOR_BEYOND_M
    n = int(np.ceil(room / FLOOR_GRID_M))
    u = np.arange(-n, n + 1) * FLOOR_GRID_M
    grid = np.stack(np.meshgrid(u, u, indexing="ij"), axis=-1).reshape(-1, 2)
    grid = grid[np.linalg.norm(grid, axis=1) <= room]
    shoulders = wrist[:2] + grid  # (S, 2)
    offsets = np.array([c.centre_base for c in circles]) - np.asarray(p_base_shoulder_xy)  # (C, 2) from the shoulder
    radii = np.array([c.radius for c in circles])
    step = 2.0 * np.pi / FLOOR_YAWS
    slack = 2.0 * FLOOR_GRID_M / np.sqrt(2.0) + np.linalg.norm(offsets, axis=1) * step / 2.0  # (C,)
    # Lower-bound distances to the footprints on a grid covering every disc centre tried (nearest grid point).
    extent = room + float(np.max(np.linalg.norm(offsets, axis=1))) + FLOOR_GRID_M
    m = int(np.ceil(extent / FLOOR_GRID_M))
    axis = np.arange(-m, m + 1) * FLOOR_GRID_M
    cells = wrist[:2] + np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1).reshape(-1, 2)
    field = np.full(len(cells), np.inf)
    # A footprint farther from the wrist than every disc centre tried plus its radius and clearance binds none.
    reach = extent + float(radii.max()) + clearance
    for polygon in footprints:
        if float(polygon.lower_distance(wrist[:2])[0]) <= reach:
            field = np.minimum(field, polygon.lower_distance(cells))
    field = field.reshape(len(axis), len(axis))
    clear = np.zeros(len(shoulders), dtype=bool)
    # A clear shoulder this near answers None whatever the other headings find: most handles stop at the first.
    within = np.linalg.norm(grid, axis=1) <= np.sqrt(r_max**2 - dz**2) + FLOOR_GRID_M / np.sqrt(2.0)
    for yaw in np.arange(FLOOR_YAWS) * step:
        c, s = np.cos(yaw), np.sin(yaw)
        ok = np.ones(len(shoulders), dtype=bool)
        for k, (ox, oy) in enumerate(offsets):
            centre = grid + np.array([c * ox - s * oy, s * ox + c * oy])
            i = np.clip(np.rint(centre / FLOOR_GRID_M).astype(int) + m, 0, 2 * m)
            ok &= field[i[:, 0], i[:, 1]] >= radii[k] + clearance - slack[k]
        clear |= ok
        if np.any(clear & within):
            return None
    # A clear pose's shoulder lies within half a grid diagonal of a grid point counted clear: none within the
    # room puts every clear shoulder beyond it.
    nearest = float(np.min(np.linalg.norm(grid[clear], axis=1), initial=room)) - FLOOR_GRID_M / np.sqrt(2.0)
    distance = float(np.hypot(max(nearest, 0.0), dz))
    return distance - r_max if distance > r_max else None


def _lift_moves(geometry: RobotGeometry, limit_margin: float) -> tuple[float, float]:
    """How far :func:`lifted` may move the shoulder down and up from its measured height (the lift's range less
    ``limit_margin`` and ``LIFT_MARGIN_M``), m; the robot must have a lift."""
    down, up = geometry.lift_range
    inside = limit_margin + LIFT_MARGIN_M
    return down + inside, up - inside


def lifted(robot: RobotDescription, geometry: RobotGeometry, height: float, limit_margin: float) -> RobotDescription:
    """The robot with its lift's home position putting the shoulder ``LIFT_ABOVE_HANDLE_M`` above a handle at
    ``height``, within the lift's range less ``limit_margin`` (the IK's) and ``LIFT_MARGIN_M``; the robot
    unchanged without a lift, and with a body lift (``base.lift``): a legged body starts at its standing height, and
    the whole-body IK crouches it (started at the handle's height, Spot crouched for every drawer below its
    shoulder)."""
    if geometry.lift_range is None or robot.base_lift:
        return robot
    lowest, highest = _lift_moves(geometry, limit_margin)
    move = float(np.clip(height + LIFT_ABOVE_HANDLE_M - geometry.p_base_shoulder[2], lowest, highest))
    q_home: FloatArray = robot.q_home.copy()
    q_home[len(robot.base_joints)] += geometry.lift_sign * move
    postures = tuple(np.where(np.arange(robot.nq) == len(robot.base_joints), q_home, q) for q in robot.q_postures)
    return replace(robot, q_home=q_home, q_postures=postures)


BAR_END_CLEARANCE_M = 0.06
"""A bar taken away from its contact point (:func:`along_bar_to_lift`) is taken at least this far inside its ends:
its posts, and half a hand's width of pads, m."""
LEVEL_BAR_AXIS_Z = 0.5
"""A bar whose axis rises less than this per metre is level: moving along it changes the height too little."""


def along_bar_to_lift(geometry: RobotGeometry, task: ArticulationTask, limit_margin: float,
                      clearance: float = BAR_END_CLEARANCE_M) -> ArticulationTask:
    """The task with its contact point moved along an upright bar (``handle_extent`` known) to the nearest height
    the robot's lift serves (:func:`lifted` would not cut the lift there) widened by what the arm itself raises
    (``RobotGeometry.reach_up``, else its reach), if that height lies ``clearance`` inside the bar's ends; the task
    unchanged for a robot without a lift, a knob, a level bar, a handle already within that band, or a bar that
    does not reach it. (A body lift, ``base.lift``, starts at standing height whatever the handle: the planner does
    not call this for one.)

    Stretch 3's mast tops out 0.11 m below a fridge's bar centre at 1.22 m, and its telescope raises nothing: the
    whole-body IK missed the pre-grasp by 47 mm level and by 10.9 deg pitched (rev_fridge_01_r3), for the whole
    10 s budget, while the same bar runs down to 0.97 m."""
    if geometry.lift_range is None or task.handle_extent is None or task.handle_axis_world is None:
        return task
    rise = _bar_rise(task)
    if abs(rise) < LEVEL_BAR_AXIS_Z:
        return task
    z = float(geometry.p_base_shoulder[2])
    lowest, highest = _lift_moves(geometry, limit_margin)
    raises = geometry.reach if geometry.reach_up is None else geometry.reach_up
    low = z + lowest - LIFT_ABOVE_HANDLE_M - raises
    high = z + highest - LIFT_ABOVE_HANDLE_M + raises
    height = handle_height(task)
    shift = (float(np.clip(height, low, high)) - height) / rise
    below, above = task.handle_extent
    if abs(shift) < 1e-3 or not below + clearance <= shift <= above - clearance:
        # A bar that does not reach the band is taken where it was: a move part of the way leaves the lift cut all
        # the same (TIAGo's 1.73 m wall-cabinet bar would have moved 1 cm down, r3 geo_island_rev_wall_00).
        return task
    return _moved_along_bar(task, shift)


def _bar_rise(task: ArticulationTask) -> float:
    """How much the handle's bar rises per metre along its axis, the part at its current state."""
    assert task.handle_axis_world is not None
    return float(T_world_part(task, [task.state_current])[0][2, :3] @ task.handle_axis_world)


def _moved_along_bar(task: ArticulationTask, shift: float) -> ArticulationTask:
    """The task with its contact point moved ``shift`` (m) along the bar's axis, its ends kept where they are."""
    assert task.handle_extent is not None and task.handle_axis_world is not None
    below, above = task.handle_extent
    return replace(task, p_world_contact=task.p_world_contact + shift * task.handle_axis_world,
                   handle_extent=(below - shift, above - shift))


def level_bar_ends(task: ArticulationTask, clearance: float = BAR_END_CLEARANCE_M) -> tuple[ArticulationTask, ...]:
    """The task with its contact point moved along a level bar (``handle_extent`` known) to ``clearance`` inside
    each of its ends, the nearer end first (none for a knob, an upright bar, unknown ends or a bar too short to move
    along by a centimetre).

    A drop-down door let go to fall keeps a base clear of where it falls open, in front of the part: a base that
    rolls only along its heading and reaches sideways (Stretch 3) stands beside the door instead, and the bar's
    centre lay 2-5 cm beyond its telescope (reseed-3 dishwashers; the bars run 0.21 m either side of it)."""
    if task.handle_extent is None or task.handle_axis_world is None:
        return ()
    if abs(_bar_rise(task)) >= LEVEL_BAR_AXIS_Z:
        return ()
    below, above = task.handle_extent
    shifts = sorted((below + clearance, above - clearance), key=abs)
    return tuple(_moved_along_bar(task, shift) for shift in shifts if abs(shift) >= 0.01 and below + clearance <= shift <= above - clearance)


@dataclass(frozen=True)
class ReachRow:
    """Whether each robot can reach one part's handle."""

    part: str
    """Part name."""
    height: float
    """Handle height where the hand takes it, m."""
    refusals: tuple[str | None, ...]
    """Per robot: None if it may reach the handle, else why not (one sentence)."""


def reach_table(scene: str | Path, robot_paths: Sequence[str | Path]) -> tuple[tuple[str, ...], tuple[ReachRow, ...]]:
    """For every part of a scene (twin folder, gt/ or capture folder, or their MJCF) and every robot file,
    whether the robot can reach its handle (``reach_refusal``); returns the robot names and one row per part.

    Raises:
        FunrecError: an unreadable scene or robot file (naming it).
    """
    from funrec_robot.robot import load_robot
    from funrec_robot.robot_geometry import measure_robot
    from funrec_robot.task_sources import load_task, locate_scene, part_names

    source = locate_scene(scene)
    robots = [load_robot(path) for path in robot_paths]
    geometries = [measure_robot(robot) for robot in robots]
    rows = []
    for name in part_names(source):
        task = load_task(source, name)
        rows.append(ReachRow(name, handle_height(task), tuple(reach_refusal(r, g, task) for r, g in zip(robots, geometries))))
    return tuple(r.name for r in robots), tuple(rows)


__all__ = ["LIFT_ABOVE_HANDLE_M", "ReachBand", "floor_reach_gap", "level_bar_ends", "ReachRow", "handle_height", "lifted", "reach_band", "reach_refusal", "reach_table"]
