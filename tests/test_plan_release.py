"""Where the part rests before the robot arrives, and how far the gripper opens to let go: a part overlapping the
scene is planned from where the contacts push it; a release that would sweep a finger into the scene opens less."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mujoco
import numpy as np
import pytest

from funrec.errors import PlanningError
from funrec_robot import build_mujoco_model, default_robot_path, load_robot, robot_indices
from funrec_robot.feasibility import release_sweep_depth, resting_state
from funrec_robot.grasp import release_command
from funrec_robot.ik import WholeBodyIK
from funrec_robot.plan import PlanConfig, plan_interaction
from funrec_robot.scene import (
    bodies_geoms,
    box_corners,
    floor_geoms,
    geom_boxes,
    part_geoms,
    part_joint,
    subtree_bodies,
)
from funrec_robot.sim_model import build_mujoco_spec
from funrec_robot.task_sources import task_from_ground_truth
from funrec_robot.whole_body import clear_release
from tests.helpers.robot_scenes import REVOLUTE_CASE, write_gt_scene

DOOR = """<mujoco><option timestep="0.002"/><worldbody>
  <geom name="counter" type="box" pos="0.45 -0.1985 {z}" size="0.2 0.2015 0.05"/>
  <body name="door" pos="0 0 0.4">
    <joint name="hinge" type="hinge" axis="0 0 1" range="0 1.5" damping="1"/>
    <geom name="panel" type="box" pos="0.2 0.01 0" size="0.2 0.01 0.3" mass="2"/>
  </body></worldbody></mujoco>"""
"""A door on a vertical hinge at the origin, its panel 0.1-0.7 m high, 0-0.4 m along x and 0-0.02 m along y when
closed. With z = 0.057 a counter's corner (top at 0.107 m, front face at y = 0.003 m, from x = 0.25 m) lies 7 mm up
and 3 mm deep in the panel's far end: the contact pushes the panel along y, open. With z = 0 the counter lies
5 cm below the panel."""


def _overlap(model: mujoco.MjModel, state: float) -> float:
    """Deepest penetration of the door panel into the counter at a door state, m."""
    data = mujoco.MjData(model)
    data.qpos[0] = state
    mujoco.mj_forward(model, data)
    return max([-float(c.dist) for c in data.contact[: data.ncon]], default=0.0)


def test_a_part_sunk_into_the_scene_rests_where_the_contacts_push_it() -> None:
    """A panel 3 mm inside the counter at state 0 is pushed open and comes to rest clear of it to MuJoCo's
    contact softness (1 mm), beyond 0.012 rad (where 0.25 m sin(state) = 3 mm); a panel clear of it stays at 0 (a
    vertical hinge: no gravity torque) to 1e-9."""
    sunk = mujoco.MjModel.from_xml_string(DOOR.format(z=0.057))
    assert _overlap(sunk, 0.0) == pytest.approx(0.003, abs=1e-6)
    rest = resting_state(sunk, 0, 0.0, 1.0, 1e-3)
    assert rest > np.deg2rad(0.5)  # PlanConfig.settle_tolerance_rad: the planner moves its start there
    assert _overlap(sunk, rest) < 0.001
    clear = mujoco.MjModel.from_xml_string(DOOR.format(z=0.0))
    assert resting_state(clear, 0, 0.0, 1.0, 1e-3) == pytest.approx(0.0, abs=1e-9)


def test_resting_state_leaves_the_model_as_it_was(robot, tmp_path) -> None:
    """``resting_state`` switches the robot's geoms off in the caller's model rather than in a copy (a copy of a
    robot's meshes took 17-27 ms of each plan), and back on: the model's collision masks are as they were, and a
    second call on the same model, or one on a fresh copy, gives the same rest to the bit."""
    gt = write_gt_scene(REVOLUTE_CASE, tmp_path)
    model = build_mujoco_model(robot, gt / "scene.xml")
    contype, conaffinity = model.geom_contype.copy(), model.geom_conaffinity.copy()
    rest = resting_state(model, part_joint(model, "part_0"), 0.05, 1.0, 1e-3)
    np.testing.assert_array_equal(model.geom_contype, contype)
    np.testing.assert_array_equal(model.geom_conaffinity, conaffinity)
    assert resting_state(model, part_joint(model, "part_0"), 0.05, 1.0, 1e-3) == rest
    assert resting_state(mujoco.MjModel.__copy__(model), part_joint(model, "part_0"), 0.05, 1.0, 1e-3) == rest


@pytest.fixture(scope="module")
def robot():
    return load_robot(default_robot_path())


@pytest.fixture(scope="module")
def released(robot, tmp_path_factory):
    gt = write_gt_scene(REVOLUTE_CASE, tmp_path_factory.mktemp("release"))
    model = build_mujoco_model(robot, gt / "scene.xml")
    task = task_from_ground_truth(gt, "part_0", model)
    plan = plan_interaction(robot, gt / "scene.xml", task, "open", model=model)
    return gt, plan


def test_a_part_resting_where_recorded_is_planned_from_there(released) -> None:
    """The bench cabinet rests at its recorded state: no settling recorded, the plan starts there."""
    _, plan = released
    assert plan.provenance["start_settled"] is None
    assert plan.start_state == 0.0


def _with_wall(robot, gt: Path, plan, gap: float, on_part: bool = False) -> tuple[mujoco.MjModel, WholeBodyIK, np.ndarray, float]:
    """The scene with a 4 cm thick wall beside the left finger, ``gap`` (m) outside its outer face with the hand
    where the release starts, holding (with ``on_part``, a piece of the part there, moving with it); returns the
    model, an IK on it, the planning joints and the part state."""
    model = build_mujoco_model(robot, gt / "scene.xml")
    indices = robot_indices(robot, model)
    k = int(np.searchsorted(plan.t, plan.segment("release").t_start))
    q, state = plan.q[k], float(plan.part_state[k])
    ik = WholeBodyIK(robot, model, part_joint(model, plan.part), plan.T_world_grasp_start[None, :3, 3], [])
    data = mujoco.MjData(model)
    data.qpos[:] = ik.full_q(q, state, plan.grasp_command)
    mujoco.mj_kinematics(model, data)
    p_world_grasp = data.site_xpos[indices.grasp_site]
    R_world_grasp = data.site_xmat[indices.grasp_site].reshape(3, 3)
    finger = subtree_bodies(model, int(model.jnt_bodyid[model.joint("robot/finger_left").id]))
    corners_grasp = (box_corners(*geom_boxes(model, data, bodies_geoms(model, finger))).reshape(-1, 3) - p_world_grasp) @ R_world_grasp
    side = 1.0 if corners_grasp[:, 1].mean() > 0.0 else -1.0
    outer = float(np.max(side * corners_grasp[:, 1]))
    p_grasp_wall = np.array([0.0, side * (outer + gap + 0.02), float(corners_grasp[:, 2].mean())])
    quat_wxyz = np.zeros(4)
    mujoco.mju_mat2Quat(quat_wxyz, R_world_grasp.ravel())
    spec = build_mujoco_spec(robot, gt / "scene.xml")
    p_world_wall, parent = p_world_grasp + R_world_grasp @ p_grasp_wall, spec.worldbody
    if on_part:
        body = int(model.jnt_bodyid[part_joint(model, plan.part)])
        R_world_body = data.xmat[body].reshape(3, 3)
        p_world_wall = R_world_body.T @ (p_world_wall - data.xpos[body])
        mujoco.mju_mat2Quat(quat_wxyz, (R_world_body.T @ R_world_grasp).ravel())
        parent = spec.body(model.body(body).name)
    parent.add_geom(name="wall", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.03, 0.02, 0.03], pos=p_world_wall, quat=quat_wxyz)
    walled = spec.compile()
    return walled, WholeBodyIK(robot, walled, part_joint(walled, plan.part), plan.T_world_grasp_start[None, :3, 3], []), q, state


def test_a_release_that_sweeps_a_finger_into_the_part_opens_less(robot, released) -> None:
    """A piece of the part 1 mm outside the left finger, and 8 mm allowed (a robot file's ``gripper.release_sweep``,
    Spot's). The planned release (the finger opens 7 mm: 5 mm gap and 2 mm squeeze) brings it at most 6 mm in: kept.
    Opening wide (to 42.5 mm, in 7 steps of 5.3 mm) it would go 9.6 mm in at the second step: the release stops at
    the first. Allowed 0.5 mm, not even the first step (4.3 mm in) is: refused, naming the piece. The hand's own
    contact with the handle is left out (allowed geoms), as the floor."""
    gt, plan = released
    model, ik, q, state = _with_wall(robot, gt, plan, 0.001, on_part=True)
    config = PlanConfig()
    floor = set(floor_geoms(model, np.flatnonzero(~np.isin(model.geom_bodyid, ik.indices.bodies))).tolist())
    handle = set(np.flatnonzero(np.isin(model.geom_bodyid, subtree_bodies(model, int(model.jnt_bodyid[part_joint(model, plan.part)])))).tolist())
    handle.discard(model.geom("wall").id)
    loose = release_command(robot, plan.grasp_command, config.grasp)
    depths, names = release_sweep_depth(model, ik, q, state, np.array([plan.grasp_command, loose]), handle, floor)
    assert depths[0] == 0.0
    assert 0.004 < depths[1] <= 0.006 + 1e-4
    assert names is not None and names[1] == "wall"
    task = task_from_ground_truth(gt, "part_0", model)
    spot_like = dataclasses.replace(robot, gripper=dataclasses.replace(robot.gripper, release_sweep=0.008))
    assert clear_release(spot_like, model, ik, task, q, state, plan.grasp_command, loose, handle, floor, config) == loose
    wide = robot.gripper.open
    first_step = plan.grasp_command + (wide - plan.grasp_command) / (config.release_sweep_samples - 1)
    capped = clear_release(spot_like, model, ik, task, q, state, plan.grasp_command, wide, handle, floor, config)
    assert capped == pytest.approx(first_step, abs=1e-12)
    tight = dataclasses.replace(robot, gripper=dataclasses.replace(robot.gripper, release_sweep=0.0005))
    with pytest.raises(PlanningError, match=r"opening gripper sweeps .* into wall"):
        clear_release(tight, model, ik, task, q, state, plan.grasp_command, wide, handle, floor, config)


def test_a_release_opens_no_finger_into_the_rest_of_the_scene(robot, released) -> None:
    """The same wall standing in the scene, 4 mm outside the left finger: the rest of the scene does not yield as
    the part does, so the 8 mm allowed there is not allowed here (a contact with it fails the check). The planned
    release (7 steps of 1 mm) stops at the fourth step, the last before the wall; 1 mm outside the finger, no step
    before the wall frees the handle: refused, naming the wall."""
    gt, plan = released
    config = PlanConfig()
    task = task_from_ground_truth(gt, "part_0", build_mujoco_model(robot, gt / "scene.xml"))
    spot_like = dataclasses.replace(robot, gripper=dataclasses.replace(robot.gripper, release_sweep=0.008))
    loose = release_command(robot, plan.grasp_command, config.grasp)
    for gap, kept in ((0.004, 4), (0.001, None)):
        model, ik, q, state = _with_wall(robot, gt, plan, gap)
        floor = set(floor_geoms(model, np.flatnonzero(~np.isin(model.geom_bodyid, ik.indices.bodies))).tolist())
        handle = set(part_geoms(model, part_joint(model, plan.part)).tolist())
        if kept is None:
            with pytest.raises(PlanningError, match=r"opening gripper sweeps .* into wall"):
                clear_release(spot_like, model, ik, task, q, state, plan.grasp_command, loose, handle, floor, config)
            continue
        released_at = clear_release(spot_like, model, ik, task, q, state, plan.grasp_command, loose, handle, floor, config)
        steps = np.linspace(plan.grasp_command, loose, config.release_sweep_samples)
        assert released_at == pytest.approx(steps[kept], abs=1e-12)
