"""A robot the project did not write, through its YAML file alone: gymnasium-robotics' Fetch."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from funrec_robot import ROBOT_PREFIX, build_mujoco_model, load_robot, reset_to_home, robot_indices

gymnasium_robotics = pytest.importorskip("gymnasium_robotics")

FETCH_YAML = Path(__file__).resolve().parents[1] / "robots" / "fetch.yaml"


@pytest.fixture(scope="module")
def fetch():
    return load_robot(FETCH_YAML)


@pytest.fixture(scope="module")
def model(fetch) -> mujoco.MjModel:
    return build_mujoco_model(fetch)


def test_fetch_loads_from_the_installed_package(fetch) -> None:
    package_dir = Path(gymnasium_robotics.__file__).resolve().parent
    assert fetch.model_path == package_dir / "envs" / "assets" / "fetch" / "reach.xml"
    assert fetch.base_type == "x+y"
    assert fetch.base_joints == ("robot0:slide0", "robot0:slide1")
    assert len(fetch.arm_joints) == 7 and fetch.nq == 9
    assert fetch.gripper.actuator is None
    # Unlimited roll joints stay unlimited; the others carry the file's ranges.
    i = fetch.joint_names.index("robot0:upperarm_roll_joint")
    assert (fetch.q_min[i], fetch.q_max[i]) == (-np.inf, np.inf)
    i = fetch.joint_names.index("robot0:shoulder_lift_joint")
    assert (fetch.q_min[i], fetch.q_max[i]) == (-1.221, 1.518)
    # The grasp frame is re-expressed: the file's site has x out of the gripper.
    np.testing.assert_allclose(fetch.T_ee_grasp[:3, 2], [1.0, 0.0, 0.0])
    assert fetch.grasp_site == "robot0:grip_grasp"


def test_fetch_gets_servos_and_loses_its_scene(fetch, model) -> None:
    indices = robot_indices(fetch, model)
    servo_names = {mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in range(model.nu)}
    for name in (*fetch.joint_names, *fetch.gripper.joints, *fetch.held_joints):
        assert f"{ROBOT_PREFIX}{name}_servo" in servo_names
    assert model.nu == fetch.nq + len(fetch.gripper.joints) + len(fetch.held_joints)
    assert model.neq == 0  # the mocap weld of the file stays behind with the mocap body
    assert model.nmocap == 0 and mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, ROBOT_PREFIX + "table0") < 0
    # kg: the file's 120.08 less its two 4 kg fingers replaced by the URDF's 0.0798 kg (robots/fetch.yaml simulation.masses)
    assert model.body_mass[indices.bodies].sum() == pytest.approx(120.08 - 2 * (4.0 - 0.0798), abs=0.1)
    slide = model.joint(ROBOT_PREFIX + "robot0:slide0")
    assert model.dof_damping[slide.dofadr[0]] == 100.0  # the YAML's override of the file's 1e11


def test_fetch_holds_home_and_tracks_a_step(fetch, model) -> None:
    data = mujoco.MjData(model)
    reset_to_home(fetch, model, data)
    indices = robot_indices(fetch, model)
    assert data.ncon == 0
    for _ in range(round(2.0 / model.opt.timestep)):
        mujoco.mj_step(model, data)
    np.testing.assert_allclose(data.qpos[indices.qpos], fetch.q_home, atol=1e-3)
    np.testing.assert_allclose(data.qpos[indices.held_qpos], indices.held_values, atol=1e-3)

    step = np.where(np.arange(fetch.nq) < 2, 0.05, 0.1)  # m for the base slides, rad for the arm
    target = fetch.q_home + step
    data.ctrl[indices.actuators] = target
    history = []
    for _ in range(round(2.0 / model.opt.timestep)):
        mujoco.mj_step(model, data)
        history.append(data.qpos[indices.qpos] - target)
    errors = np.array(history)
    assert np.all(np.isfinite(errors)) and np.abs(data.qvel).max() < 1e-2
    overshoot = (errors * np.sign(step)).max(axis=0) / np.abs(step)
    assert np.all(overshoot < 0.25), overshoot
    # forearm_roll has a 10 N m/rad spring in the file: 1 mrad of steady error against kp 1000.
    assert np.all(np.abs(errors[-1]) < 2e-3), errors[-1]
    data.ctrl[indices.gripper_actuators] = fetch.gripper.closed
    for _ in range(round(1.5 / model.opt.timestep)):
        mujoco.mj_step(model, data)
    np.testing.assert_allclose(data.qpos[indices.gripper_qpos], fetch.gripper.closed, atol=2e-3)


def test_fetch_ik_unloads_the_wrist_through_the_null_space(fetch, tmp_path) -> None:
    from funrec_robot.ik import IKConfig, WholeBodyIK
    from funrec_robot.scene import part_joint
    from tests.helpers.robot_scenes import PRISMATIC_CASE, write_gt_scene

    model = build_mujoco_model(fetch, write_gt_scene(PRISMATIC_CASE, tmp_path) / "scene.xml")
    config = IKConfig(gravity_free_share=0.2)
    ik = WholeBodyIK(fetch, model, part_joint(model, "part_0"), np.zeros((1, 3)), [], config)
    gravity = ik.tasks[2]
    # Elbow up, wrist straight: the hand loads the wrist flex joint with about 26 % of its limit (measured with the
    # URDF's 0.08 kg fingers; the file's 4 kg fingers gave 55 %), above the 20 % share the IK is asked to keep free of.
    q = fetch.q_home.copy()
    q[fetch.joint_names.index("robot0:wrist_flex_joint")] = 0.0
    T = ik.grasp_pose(q, 0.0, fetch.gripper.open)
    loaded = float(np.abs(gravity._load(ik.full_q(q, 0.0, fetch.gripper.open))).max())
    assert loaded > ik.config.gravity_free_share
    q_kept, e_p, e_r = ik.solve(T, q, q, 0.0, fetch.gripper.open)
    np.testing.assert_allclose(q_kept, q, atol=1e-9)  # already on target: without unloading nothing moves
    q_free, e_p, e_r = ik.solve(T, q, q, 0.0, fetch.gripper.open, unload=True)
    # The hand stays on its target within the IK's own tolerances (1 mm, 0.01 rad) ...
    assert e_p < ik.config.position_tolerance and e_r < ik.config.orientation_tolerance
    np.testing.assert_allclose(ik.grasp_pose(q_free, 0.0, fetch.gripper.open)[:3, 3], T[:3, 3], atol=ik.config.position_tolerance)
    # ... while the worst arm joint's gravity share drops by at least 0.02 (half a N m at the wrist; the hinge
    # only pulls above 20 % here, so a drop is all it can promise).
    unloaded = float(np.abs(gravity._load(ik.full_q(q_free, 0.0, fetch.gripper.open))).max())
    assert unloaded < loaded - 0.02, (loaded, unloaded)


def test_fetch_ik_keeps_its_upper_arm_off_its_torso(fetch, model) -> None:
    """On the right cabinet door Fetch's shoulder lift link met its torso in the check (2 mm apart at home, a
    grandchild of the torso, so mink gave no pair): its shoulder pan servo then asked 41.6 of 33.8 N m. The IK
    has the pair now, with the arm's self-collision gap."""
    from funrec_robot.collision_limit import BoxedCollisionLimit
    from funrec_robot.ik import IKConfig, WholeBodyIK

    ik = WholeBodyIK(fetch, model, 0, np.zeros((1, 3)), [], IKConfig())  # the robot alone: no part to freeze
    limits = [lim for lim in ik.limits if isinstance(lim, BoxedCollisionLimit)]
    names = {frozenset((model.body(model.geom_bodyid[a]).name, model.body(model.geom_bodyid[b]).name))
             for lim in limits for a, b in lim.geom_id_pairs}
    assert frozenset(("robot/robot0:torso_lift_link", "robot/robot0:shoulder_lift_link")) in names
    assert limits[-1].minimum_distance_from_collisions == IKConfig().wrist_collision_distance


def test_fetch_ik_holds_its_upper_arm_where_the_path_starts(fetch, model) -> None:
    """Held at its bound, the shoulder lift link crept towards the torso at second order (0.1 mm per IK step; on
    plain_rev_fridge_00_r3 from 5 mm to 0.8 mm along the door's path, inside the torso's 1 mm contact margin, and the
    pan servo pushed 18-50 N m of its 33.8 against the contact). From 2.6 mm apart (that plan's arm, 14 s into the
    door's swing), three 1 cm steps of the hand backwards: the robot's own pairs are held where the path started them,
    within the 0.1 mm the half-gap gain leaves of a creep that size (not pushed open to their 5 mm: Fetch's arm lies
    2 mm from its torso at home); held only at the bound, as mink does, they end 0.4 mm closer."""
    from funrec_robot.ik import IKConfig, WholeBodyIK

    q = np.array([-2.07, 0.486, 0.96, -1.016, 1.594, 2.201, 1.129, -1.918, -1.02])
    torso = model.geom(ROBOT_PREFIX + "robot0:torso_lift_link").id
    upper = model.geom(ROBOT_PREFIX + "robot0:shoulder_lift_link").id
    gaps = {}
    for recover in (True, False):
        ik = WholeBodyIK(fetch, model, 0, np.zeros((1, 3)), [], IKConfig())
        limits = [limit for limit in ik.limits if getattr(limit, "recover", False)]
        assert len(limits) == 1
        limits[0].recover = recover
        T = ik.grasp_pose(q, 0.0, fetch.gripper.open)
        start = mujoco.mj_geomDistance(model, ik.configuration.data, torso, upper, 0.1, np.zeros(6))
        targets = np.repeat(T[None], 3, axis=0)
        targets[:, 0, 3] -= [0.01, 0.02, 0.03]
        result = ik.track(targets, np.zeros(3), q, np.repeat(q[None], 3, axis=0), fetch.gripper.open)
        assert result.position_error.max() < ik.config.position_tolerance
        ik.grasp_pose(result.q[-1], 0.0, fetch.gripper.open)
        gaps[recover] = mujoco.mj_geomDistance(model, ik.configuration.data, torso, upper, 0.1, np.zeros(6))
    assert start == pytest.approx(0.0026, abs=2e-4)
    assert gaps[True] > start - 1e-4, (start, gaps)
    assert gaps[False] < start - 2e-4, (start, gaps)
