"""load_robot reads a robot YAML file and every mistake in it is reported with the file and the valid names."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from funrec_robot import (
    DEFAULT_ROBOT,
    RobotDescriptionError,
    UnknownNameError,
    default_robot_path,
    find_robots,
    load_robot,
    resolve_robot,
)

ROBOTS = Path(__file__).resolve().parents[1] / "robots"


def _write(tmp_path: Path, document: dict[str, Any]) -> Path:
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(document, sort_keys=False))
    return path


@pytest.fixture()
def document() -> dict[str, Any]:
    """The default robot's YAML with absolute model paths, to edit and write elsewhere."""
    document = yaml.safe_load((ROBOTS / "funrec_mm.yaml").read_text())
    for key in ("model", "urdf"):
        document[key] = str((ROBOTS / document[key]).resolve())
    return document


def test_default_robot_loads() -> None:
    robot = load_robot(default_robot_path())
    assert robot.name == DEFAULT_ROBOT
    assert robot.base_type == "holonomic"
    assert robot.base_joints == ("base_x", "base_y", "base_yaw")
    assert robot.arm_joints == tuple(f"arm_joint{i}" for i in range(1, 8))
    assert robot.nq == 10
    for array in (robot.q_home, robot.q_min, robot.q_max, robot.v_max, robot.a_max, robot.effort_max):
        assert array.shape == (10,) and not array.flags.writeable
    assert np.all(robot.q_min <= robot.q_home) and np.all(robot.q_home <= robot.q_max)
    assert np.all(np.isfinite(robot.v_max)) and np.all(np.isfinite(robot.a_max))
    assert robot.gripper.actuator == "gripper" and robot.gripper.joints == ("finger_left", "finger_right")
    assert (robot.gripper.open, robot.gripper.closed) == (0.0425, 0.0)
    assert robot.ee_site == robot.grasp_site == "grasp_site"
    np.testing.assert_array_equal(robot.T_ee_grasp, np.eye(4))
    assert robot.servos == {}  # every joint of this model has its own actuator
    assert robot.urdf_path is not None and robot.urdf_path.name == "funrec_mm.urdf"


def test_catalog_finds_robots_by_name_and_path(tmp_path: Path) -> None:
    assert {path.stem for path in find_robots()} >= {"funrec_mm", "fetch"}
    assert resolve_robot("funrec_mm") == ROBOTS / "funrec_mm.yaml"
    assert resolve_robot(ROBOTS / "fetch.yaml") == ROBOTS / "fetch.yaml"
    with pytest.raises(RobotDescriptionError, match=r"no_such_robot: no such robot YAML file .*'fetch', 'funrec_mm'"):
        resolve_robot("no_such_robot")
    with pytest.raises(RobotDescriptionError, match="no such robots folder"):
        find_robots(tmp_path / "missing")


def test_grasp_frame_axes_build_a_rotation(tmp_path: Path, document) -> None:
    document["ee"] = {
        "site": "grasp_site",
        "approach_axis": [1, 0, 0],
        "closing_axis": [0, -1, 0],
        "offset": [0.01, 0, 0],
    }
    robot = load_robot(_write(tmp_path, document))
    R_ee_grasp = robot.T_ee_grasp[:3, :3]
    np.testing.assert_allclose(R_ee_grasp @ [0, 0, 1], [1, 0, 0], atol=1e-12)  # grasp z = approach
    np.testing.assert_allclose(R_ee_grasp @ [0, 1, 0], [0, -1, 0], atol=1e-12)  # grasp y = closing
    assert np.linalg.det(R_ee_grasp) == pytest.approx(1.0)
    np.testing.assert_allclose(robot.T_ee_grasp[:3, 3], [0.01, 0, 0])
    assert robot.grasp_site == "grasp_site_grasp"


def test_limit_overrides_replace_model_values(tmp_path: Path, document) -> None:
    document["limits"]["position"] = {"arm_joint1": [-1.0, 1.0]}
    document["limits"]["effort"] = {"arm_joint1": 50.0}
    robot = load_robot(_write(tmp_path, document))
    i = robot.joint_names.index("arm_joint1")
    assert (robot.q_min[i], robot.q_max[i], robot.effort_max[i]) == (-1.0, 1.0, 50.0)


def test_a_robot_file_sets_how_far_its_fingers_open_to_let_go(tmp_path: Path, document) -> None:
    """``gripper.release_gap`` (Fetch's 15 mm: its damped arm tracked the retreat loosely, and 5 mm fingers dragged
    the handle, 57-67 N) replaces the planner's ``GraspConfig.release_gap`` (5 mm) for that robot alone."""
    from funrec_robot.grasp import GraspConfig, release_command

    config = GraspConfig()
    default = load_robot(_write(tmp_path, document))
    document["gripper"]["release_gap"] = 0.015
    wider = load_robot(_write(tmp_path, document))
    assert default.gripper.release_gap is None and wider.gripper.release_gap == 0.015
    holding = default.gripper.command(0.01)
    gripper = wider.gripper
    # each finger 10 mm further from the handle: the command moves by 10 mm of finger travel, within the span
    step = release_command(wider, holding, config) - release_command(default, holding, config)
    assert step == pytest.approx(gripper.command(0.010) - gripper.closed)
    document["gripper"]["release_gap"] = -0.01
    with pytest.raises(RobotDescriptionError, match="gripper.release_gap"):
        load_robot(_write(tmp_path, document))


def test_a_robot_file_sets_how_it_lets_a_falling_door_go(tmp_path: Path, document) -> None:
    """``gripper.fall_rest_force`` and ``gripper.fall_retreat_scale`` (Stretch 3's rubber fingertip pads turn under
    a door's weight and hook its edge) replace the planner's ``PlanConfig.fall_rest_force`` and
    ``falling_retreat_scale`` for that robot alone; a scale is a fraction of the usual speed, in (0, 1]."""
    default = load_robot(_write(tmp_path, document))
    document["gripper"]["fall_rest_force"] = 7.0
    document["gripper"]["fall_retreat_scale"] = 0.5
    robot = load_robot(_write(tmp_path, document))
    assert (default.gripper.fall_rest_force, default.gripper.fall_retreat_scale) == (None, None)
    assert (robot.gripper.fall_rest_force, robot.gripper.fall_retreat_scale) == (7.0, 0.5)
    for key, value in (("fall_retreat_scale", 1.5), ("fall_retreat_scale", 0.0), ("fall_rest_force", -1.0)):
        bad = {**document, "gripper": {**document["gripper"], key: value}}
        with pytest.raises(RobotDescriptionError, match=f"gripper.{key}"):
            load_robot(_write(tmp_path, bad))


def test_fixed_base_robot(tmp_path: Path, document) -> None:
    """Base joints left out of 'base' must then be held; the base type becomes 'fixed'."""
    del document["base"]
    document["held_joints"] = {"base_x": 0.0, "base_y": 0.0, "base_yaw": 0.0}
    for key in ("velocity", "acceleration"):
        for name in ("base_x", "base_y", "base_yaw"):
            del document["limits"][key][name]
    robot = load_robot(_write(tmp_path, document))
    assert robot.base_type == "fixed" and robot.nq == 7


# ---------------------------------------------------------------- errors name the file and the valid names


def test_unknown_arm_joint_lists_the_joints(tmp_path: Path, document) -> None:
    document["arm_joints"][6] = "arm_joint9"
    with pytest.raises(
        UnknownNameError,
        match=r"bad\.yaml: arm_joints: joint 'arm_joint9' not in the model; valid joints: 'base_x', 'base_y', "
        r"'base_yaw', 'arm_joint1', .*'finger_right'",
    ):
        load_robot(_write(tmp_path, document))


def test_unknown_site_lists_the_sites(tmp_path: Path, document) -> None:
    document["ee"]["site"] = "tool0"
    with pytest.raises(
        UnknownNameError, match=r"bad\.yaml: ee\.site: site 'tool0' not in the model; valid sites: 'grasp_site'"
    ):
        load_robot(_write(tmp_path, document))


def test_unknown_actuator_lists_the_actuators(tmp_path: Path, document) -> None:
    document["gripper"]["actuator"] = "hand"
    with pytest.raises(
        UnknownNameError,
        match=r"bad\.yaml: gripper\.actuator: actuator 'hand' not in the model; valid actuators: 'base_x'.*'gripper'",
    ):
        load_robot(_write(tmp_path, document))


def test_unknown_root_body_lists_the_bodies(tmp_path: Path, document) -> None:
    document["root_body"] = "chassis"
    with pytest.raises(
        UnknownNameError,
        match=r"bad\.yaml: root_body: body 'chassis' not in the model; valid bodies: 'base_link', 'torso_link'",
    ):
        load_robot(_write(tmp_path, document))


def test_unknown_key_lists_the_keys(tmp_path: Path, document) -> None:
    document["gripper"]["force"] = 20
    with pytest.raises(
        RobotDescriptionError,
        match=r"bad\.yaml: gripper: unknown key 'force'; valid keys: 'joints', 'actuator', 'open', 'closed'",
    ):
        load_robot(_write(tmp_path, document))
    del document["gripper"]["force"]
    document["arms"] = document.pop("arm_joints")
    with pytest.raises(
        RobotDescriptionError, match=r"bad\.yaml: \(top level\): unknown key 'arms'; valid keys: 'name', 'model'"
    ):
        load_robot(_write(tmp_path, document))


def test_unlisted_joint_is_an_error(tmp_path: Path, document) -> None:
    document["gripper"]["joints"] = ["finger_left"]
    with pytest.raises(
        RobotDescriptionError, match=r"bad\.yaml: robot joints not listed: 'finger_right'; put each under base"
    ):
        load_robot(_write(tmp_path, document))


def test_joint_in_two_groups_is_an_error(tmp_path: Path, document) -> None:
    document["held_joints"] = {"arm_joint7": 0.0}
    with pytest.raises(RobotDescriptionError, match=r"bad\.yaml: joints listed in more than one group: 'arm_joint7'"):
        load_robot(_write(tmp_path, document))


def test_base_joint_must_move_along_its_axis(tmp_path: Path, document) -> None:
    document["base"] = {"x": "base_y", "y": "base_x", "yaw": "base_yaw"}
    with pytest.raises(
        RobotDescriptionError, match=r"bad\.yaml: base\.x: joint 'base_y' must be a slide along the root body's x axis"
    ):
        load_robot(_write(tmp_path, document))


def test_missing_limits_are_listed(tmp_path: Path, document) -> None:
    del document["limits"]["acceleration"]["arm_joint3"]
    del document["limits"]["acceleration"]["base_yaw"]
    with pytest.raises(
        RobotDescriptionError,
        match=r"bad\.yaml: limits\.acceleration: no acceleration limit for 'base_yaw', 'arm_joint3'",
    ):
        load_robot(_write(tmp_path, document))


def test_home_outside_limits(tmp_path: Path, document) -> None:
    document["home"]["arm_joint4"] = 3.0
    with pytest.raises(RobotDescriptionError, match=r"bad\.yaml: home: outside the position limits: 'arm_joint4'"):
        load_robot(_write(tmp_path, document))


def test_postures_fill_in_from_home_and_are_checked(tmp_path: Path, document) -> None:
    document["postures"] = [{"arm_joint1": 0.5}, {"arm_joint7": -0.25}]
    robot = load_robot(_write(tmp_path, document))
    assert len(robot.q_postures) == 2
    changed = [np.flatnonzero(q != robot.q_home).tolist() for q in robot.q_postures]
    assert changed == [[robot.joint_names.index("arm_joint1")], [robot.joint_names.index("arm_joint7")]]
    assert robot.q_postures[0][robot.joint_names.index("arm_joint1")] == 0.5
    document["postures"] = [{"arm_joint4": 3.0}]
    with pytest.raises(RobotDescriptionError, match=r"bad\.yaml: postures\[0\]: outside the position limits: 'arm_joint4'"):
        load_robot(_write(tmp_path, document))
    document["postures"] = [{"arm_joint9": 0.0}]
    with pytest.raises(UnknownNameError, match=r"postures\[0\]"):
        load_robot(_write(tmp_path, document))
    document["postures"] = {"arm_joint1": 0.5}
    with pytest.raises(RobotDescriptionError, match=r"postures: expected a list"):
        load_robot(_write(tmp_path, document))


def test_servo_for_an_actuated_joint(tmp_path: Path, document) -> None:
    document["simulation"]["servos"] = {"arm_joint1": {"kp": 10.0, "kv": 1.0}}
    with pytest.raises(
        RobotDescriptionError,
        match=r"bad\.yaml: simulation\.servos: these joints already have an actuator in the model: 'arm_joint1'",
    ):
        load_robot(_write(tmp_path, document))


def test_wrong_types_are_reported(tmp_path: Path, document) -> None:
    document["gripper"]["open"] = "wide"
    with pytest.raises(RobotDescriptionError, match=r"bad\.yaml: gripper\.open: expected a finite number, got 'wide'"):
        load_robot(_write(tmp_path, document))
    document["gripper"]["open"] = 0.1
    with pytest.raises(RobotDescriptionError, match=r"bad\.yaml: gripper\.open: 0\.1 outside the command range"):
        load_robot(_write(tmp_path, document))


def test_model_paths(tmp_path: Path, document) -> None:
    document["model"] = "package://no_such_package_funrec/robot.xml"
    with pytest.raises(
        RobotDescriptionError,
        match=r"bad\.yaml: model: 'package://no_such_package_funrec/robot\.xml': Python package 'no_such_package_funrec' is not installed",
    ):
        load_robot(_write(tmp_path, document))
    document["model"] = "missing.xml"
    with pytest.raises(RobotDescriptionError, match=r"bad\.yaml: model: 'missing\.xml': no such file"):
        load_robot(_write(tmp_path, document))
    (tmp_path / "broken.xml").write_text("<mujoco><worldbody><body><joint type='hinge'/></body></worldbody></mujoco>")
    document["model"] = "broken.xml"
    with pytest.raises(RobotDescriptionError, match=r"bad\.yaml: model: MuJoCo cannot compile .*broken\.xml"):
        load_robot(_write(tmp_path, document))
    with pytest.raises(RobotDescriptionError, match=r"missing\.yaml: no such robot YAML file"):
        load_robot(tmp_path / "missing.yaml")


def test_grasp_site_follows_a_rotated_ee_site(tmp_path: Path) -> None:
    """An end-effector site written with euler angles: the added grasp site sits at T_body_ee @ T_ee_grasp."""
    import mujoco

    from funrec_robot import build_mujoco_model, robot_indices

    (tmp_path / "arm.xml").write_text(
        """<mujoco><compiler angle="degree"/><worldbody><body name="link" pos="0 0 1">
        <joint name="j" type="hinge" axis="0 0 1" range="-90 90"/><geom type="capsule" size="0.05 0.2"/>
        <site name="tool" pos="0.1 0 0.3" euler="0 90 0"/></body></worldbody>
        <actuator><position name="j" joint="j" kp="10"/></actuator></mujoco>"""
    )
    (tmp_path / "arm.yaml").write_text(
        "model: arm.xml\narm_joints: [j]\ngripper: {joints: [], open: 0, closed: 0}\n"
        "ee: {site: tool, approach_axis: [1, 0, 0], closing_axis: [0, 1, 0]}\n"
        "limits: {velocity: {j: 1}, acceleration: {j: 1}, effort: {j: 5}}\n"
    )
    robot = load_robot(tmp_path / "arm.yaml")
    assert robot.base_type == "fixed" and robot.q_max[0] == pytest.approx(np.pi / 2)
    model = build_mujoco_model(robot)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    indices = robot_indices(robot, model)
    tool = model.site("robot/tool").id
    T_world_ee = np.eye(4)
    T_world_ee[:3, :3], T_world_ee[:3, 3] = data.site_xmat[tool].reshape(3, 3), data.site_xpos[tool]
    T_world_grasp = T_world_ee @ robot.T_ee_grasp
    np.testing.assert_allclose(data.site_xmat[indices.grasp_site].reshape(3, 3), T_world_grasp[:3, :3], atol=1e-9)
    np.testing.assert_allclose(data.site_xmat[indices.grasp_site].reshape(3, 3)[:, 2], [0, 0, -1], atol=1e-9)
