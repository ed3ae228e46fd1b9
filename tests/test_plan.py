"""Planning on ground-truth scenes: the task read off the scene geometry, base placement clear of the scene,
timed plans within the robot's limits, plan.json round trip, errors that name what failed."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from funrec.errors import FunrecError, PlanningError
from funrec.formats.affordances import Affordances, Interaction, PartAffordance, write_affordances
from funrec.formats.twin import TwinArticulation, make_part, write_articulation
from funrec_robot import build_mujoco_model, default_robot_path, load_robot, robot_indices
from funrec_robot.errors import Refusal
from funrec_robot.feasibility import kinematic_collisions
from funrec_robot.grasp_frames import roll_to_hold, rotation_about_grasp_axis
from funrec_robot.plan import PlanConfig, plan_interaction
from funrec_robot.plan_file import read_plan, write_plan
from funrec_robot.retime import limit_use
from funrec_robot.scene import bodies_geoms, floor_geoms, part_joint
from funrec_robot.task import resolve_target
from funrec_robot.task_sources import locate_scene, task_from_ground_truth, task_from_twin
from tests.helpers.robot_scenes import PRISMATIC_CASE, REVOLUTE_CASE, write_gt_scene

ACCELERATION_TOL = 0.03
"""Relative excess of finite-difference accelerations of 10 ms plan samples over the limits accepted (a
jump in a piecewise-constant acceleration read by a central difference; the limits hold on the dense check)."""


@pytest.fixture(scope="module")
def robot():
    return load_robot(default_robot_path())


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("gt_scenes")
    return {name: write_gt_scene(name, root) for name in (REVOLUTE_CASE, PRISMATIC_CASE)}


@pytest.fixture(scope="module")
def revolute(robot, scenes):
    gt = scenes[REVOLUTE_CASE]
    model = build_mujoco_model(robot, gt / "scene.xml")
    task = task_from_ground_truth(gt, "part_0", model)
    return gt, model, task, plan_interaction(robot, gt / "scene.xml", task, "open", model=model)


def test_task_reads_approach_handle_and_standoff_off_the_scene(scenes) -> None:
    """The cabinets stand against the +y wall: the approach (into the front) is +y, from the panel's normal."""
    door = task_from_ground_truth(scenes[REVOLUTE_CASE], "part_0")
    np.testing.assert_allclose(door.approach_world, [0.0, 1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(np.abs(door.handle_axis_world), [0.0, 0.0, 1.0], atol=1e-6)  # vertical bar
    assert 0.005 < door.surface_offset < 0.05 and 0.004 < door.handle_width < 0.03
    drawer = task_from_ground_truth(scenes[PRISMATIC_CASE], "part_0")
    np.testing.assert_allclose(np.abs(drawer.handle_axis_world), [1.0, 0.0, 0.0], atol=1e-6)  # horizontal bar
    assert drawer.joint_type == "prismatic" and drawer.demo_states.size > 0


def test_base_placement_is_collision_free(robot, revolute) -> None:
    gt, model, task, plan = revolute
    assert plan.provenance["placement_clearance_m"] >= PlanConfig().placement.clearance - 1e-3
    indices = robot_indices(robot, model)
    data = mujoco.MjData(model)
    scene = np.flatnonzero(~np.isin(model.geom_bodyid, indices.bodies))
    ignore = set(floor_geoms(model, scene).tolist())
    robot_geoms = set(bodies_geoms(model, indices.bodies).tolist())
    for i in (0, plan.segment("actuate").start, plan.segment("actuate").end):
        data.qpos[:] = model.qpos0
        data.qpos[indices.qpos] = plan.q[i]
        data.qpos[model.jnt_qposadr[part_joint(model, "part_0")]] = plan.part_state[i]
        mujoco.mj_forward(model, data)
        base_contacts = [
            (model.geom(c.geom1).name, model.geom(c.geom2).name)
            for c in data.contact[: data.ncon]
            if (c.geom1 in robot_geoms) != (c.geom2 in robot_geoms)
            and not {c.geom1, c.geom2} & ignore
            and "base" in model.geom(c.geom1 if c.geom1 in robot_geoms else c.geom2).name
        ]
        assert not base_contacts, (i, base_contacts)


def test_plan_replays_without_forbidden_contacts(robot, revolute) -> None:
    """Kinematic replay of the whole plan (every 50 ms): the robot touches nothing but the handle."""
    gt, model, task, plan = revolute
    assert kinematic_collisions(robot, model, plan) == []


def test_plan_is_labelled_and_within_the_robot_limits(robot, revolute) -> None:
    *_, plan = revolute
    assert [s.label for s in plan.segments] == ["approach", "grasp", "actuate", "release", "retreat"]
    assert plan.joint_names == robot.joint_names
    np.testing.assert_allclose(np.diff(plan.t), 0.01, atol=1e-9)
    use = limit_use(plan.t, plan.qd, robot.v_max, robot.a_max)
    assert use.velocity <= 1.0 + 1e-6 and use.acceleration <= 1.0 + ACCELERATION_TOL, use
    assert np.all(plan.q >= robot.q_min - 1e-9) and np.all(plan.q <= robot.q_max + 1e-9)
    actuate = plan.segment("actuate")
    assert np.all(plan.gripper_command[actuate.start : actuate.end + 1] == plan.grasp_command)
    assert plan.part_state[actuate.end] == pytest.approx(plan.target_state, abs=1e-6)
    for key in ("robot_sha256", "scene_sha256", "task_files", "plan_time_s"):
        assert key in plan.provenance


def test_plan_json_round_trip(tmp_path, revolute) -> None:
    *_, plan = revolute
    back = read_plan(write_plan(tmp_path / "plan.json", plan))
    for field in dataclasses.fields(plan):
        a, b = getattr(plan, field.name), getattr(back, field.name)
        if isinstance(a, np.ndarray):
            np.testing.assert_allclose(b, a, atol=1e-6)
        elif field.name != "provenance":
            assert a == b, field.name


def test_bad_plan_file_names_the_field(tmp_path) -> None:
    path = tmp_path / "plan.json"
    path.write_text('{"format": "funrec-plan/1", "joint_names": ["a"], "t": [0, 0.01], "q": [[0]]}')
    with pytest.raises(FunrecError, match=r"plan\.json.*'q'"):
        read_plan(path)


def test_targets_outside_the_range_are_refused_with_the_range(scenes) -> None:
    task = task_from_ground_truth(scenes[PRISMATIC_CASE], "part_0")
    assert resolve_target(task, "open") == task.state_range[1]
    with pytest.raises(PlanningError, match=r"part 'part_0': target 2 m outside the part's range \[0, 0\.433\]"):
        resolve_target(task, 2.0)
    with pytest.raises(PlanningError, match="expected a joint state in m or one of open, close, demo"):
        resolve_target(task, "ajar")


def _fixture_affordance(name: str, contact: list[float], T_world_grasp: np.ndarray, states: list[float]) -> PartAffordance:
    """A hand-written affordance (test fixture, not a reconstruction): one hold over ``states`` at 10 fps."""
    n = len(states)
    return PartAffordance(
        name, "revolute", np.asarray(contact, dtype=float), T_world_grasp, True,
        (Interaction(np.arange(4, 4 + n), (4 + np.arange(n)) / 10.0, np.asarray(states, dtype=float)),),
        np.asarray([contact], dtype=float), np.ones(1), np.zeros(0), np.zeros((0, 3)),
    )


def test_task_from_twin_maps_the_affordance_frame_into_the_scene(tmp_path) -> None:
    """funrec-affordances/1 grasp frames have z = approach and x = handle axis (funrec.affordance.contacts); the task's
    handle axis is that x, the demonstration is the first hold from its start, and all move with T_scene_twin."""
    part = make_part("part_0", "revolute", [0.0, 0.0, 1.0], [1.0, 2.0, 0.0], [0, 1], [0.0, 0.5], (0.0, 1.5))
    write_articulation(tmp_path / "articulation.json", TwinArticulation(frame_count=2, parts=(part,)))
    T_world_grasp = np.eye(4)
    T_world_grasp[:3, :3] = np.column_stack([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # x up, z = -y
    T_world_grasp[:3, 3] = [1.3, 1.9, 0.8]
    affordance = _fixture_affordance("part_0", [1.3, 1.9, 0.8], T_world_grasp, [0.0, 0.2, 0.5])
    write_affordances(tmp_path / "affordances.json", Affordances((affordance,), (), "capture", 10.0))
    T_scene_twin = np.eye(4)
    T_scene_twin[:3, :3] = Rotation.from_euler("z", np.pi).as_matrix()  # the twin's y points the scene's -y
    T_scene_twin[:3, 3] = [0.5, 0.0, 0.0]
    task = task_from_twin(tmp_path, "part_0", T_scene_twin)
    # exact arithmetic on small integers and a 180-degree rotation: only round-off remains
    np.testing.assert_allclose(task.approach_world, [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(task.handle_axis_world, [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(task.p_world_contact, [-0.8, -1.9, 0.8], atol=1e-12)
    np.testing.assert_allclose(task.pivot_world, [-0.5, -2.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(task.demo_times, [0.0, 0.1, 0.2], atol=1e-12)
    np.testing.assert_allclose(task.demo_states, [0.0, 0.2, 0.5], atol=1e-12)
    assert task.source.startswith("twin:") and task.grasp_source == "affordances"
    with pytest.raises(PlanningError, match="has 1 hold"):
        task_from_twin(tmp_path, "part_0", interaction=3)


def _door_twin(root, mesh) -> None:
    """A twin folder in ``root`` without affordances: one door (``mesh``, a trimesh) hinged on the vertical line
    x = 1.0, y = 0, tracked by cameras at (1.2, -2.0, 1.4)."""
    from funrec.formats.camera_poses import write_camera_poses

    (root / "meshes").mkdir()
    mesh.export(root / "meshes" / "part_0.ply")
    part = make_part("part_0", "revolute", [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0, 1], [0.0, 0.5], (0.0, 1.5),
                     mesh="meshes/part_0.ply")
    write_articulation(root / "articulation.json", TwinArticulation(frame_count=2, parts=(part,)))
    T_world_camera = np.tile(np.eye(4), (2, 1, 1))
    T_world_camera[:, :3, 3] = [1.2, -2.0, 1.4]
    write_camera_poses(root / "camera_poses.txt", T_world_camera)


def test_task_from_twin_without_affordances_grasps_the_mesh_and_says_so(tmp_path, caplog) -> None:
    """A door 0.5 m wide (x from 1.0 to 1.5), hinged on its x = 1.0 edge, facing cameras at y = -2: the
    fallback grasp is on its front (y = -0.02), MESH_GRASP_INSET_M in from the free edge, at mid-height."""
    import trimesh

    from funrec_robot.task_sources import MESH_GRASP_INSET_M

    door = trimesh.creation.box(extents=[0.5, 0.02, 0.8])
    door.apply_translation([1.25, -0.01, 0.9])
    _door_twin(tmp_path, door)
    with caplog.at_level("WARNING"):
        task = task_from_twin(tmp_path, "part_0")
    # box vertices are exact; the mesh centroid is the box centre, so the numbers are exact to round-off
    np.testing.assert_allclose(task.p_world_contact, [1.5 - MESH_GRASP_INSET_M, -0.02, 0.9], atol=1e-9)
    np.testing.assert_allclose(task.approach_world, [0.0, 1.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(np.abs(task.handle_axis_world), [0.0, 0.0, 1.0], atol=1e-9)
    assert task.grasp_source.startswith("mesh fallback") and "affordances.json is missing" in task.grasp_source
    assert "no affordance" in caplog.text


def test_task_from_twin_without_affordances_grasps_a_knob_the_mesh_shows(tmp_path) -> None:
    """The same door with a knob (radius 1.6 cm, 2.5 cm proud of the front) near its top at the free edge, as on
    the twin of geo_angled_rev_cabinet_00 whose door the hand never came near: the grasp is on the knob (within
    3 mm of its centre across the front: the knob's proud half's centroid, moved to the knob's middle by
    measure_handle), not at the door's mid-height, and taken as a knob (no handle axis)."""
    import trimesh

    door = trimesh.creation.box(extents=[0.5, 0.02, 0.8])
    for _ in range(5):  # vertices all over the faces, as a fused mesh has
        door = door.subdivide()
    door.apply_translation([1.25, -0.01, 0.9])
    knob_centre = np.array([1.45, -0.045, 1.2])
    knob = trimesh.creation.icosphere(subdivisions=3, radius=0.016)
    knob.apply_translation(knob_centre)
    _door_twin(tmp_path, trimesh.util.concatenate([door, knob]))
    task = task_from_twin(tmp_path, "part_0")
    np.testing.assert_allclose(task.p_world_contact[[0, 2]], knob_centre[[0, 2]], atol=0.003)
    # The knob's points tilt the mesh's principal plane by about a degree (0.016 in a component).
    np.testing.assert_allclose(task.approach_world, [0.0, 1.0, 0.0], atol=0.02)
    assert task.handle_axis_world is None
    assert "a handle the part mesh shows" in task.grasp_source


def test_unknown_part_lists_the_parts(scenes) -> None:
    with pytest.raises(PlanningError, match=r"no part 'part_7'; parts: 'part_0'"):
        task_from_ground_truth(scenes[PRISMATIC_CASE], "part_7")


def test_locate_scene_accepts_folders_and_files(scenes, tmp_path) -> None:
    gt = scenes[PRISMATIC_CASE]
    assert locate_scene(gt).scene_xml == gt / "scene.xml"
    assert locate_scene(gt.parent).kind == "gt"
    assert locate_scene(gt / "scene.xml").folder == gt
    with pytest.raises(PlanningError, match="articulation.json"):
        locate_scene(tmp_path)


def test_unreachable_part_is_refused_at_once_in_one_sentence(robot, scenes) -> None:
    gt = scenes[PRISMATIC_CASE]
    task = task_from_ground_truth(gt, "part_0")
    high = dataclasses.replace(task, p_world_contact=task.p_world_contact + [0.0, 0.0, 1.6])  # a handle at 2.4 m
    started = time.process_time()
    with pytest.raises(Refusal, match=r"part 'part_0': handle at 2\.40 m; funrec_mm reaches 0\.\d\d-\d\.\d\d m$"):
        plan_interaction(robot, gt / "scene.xml", high, "open", config=dataclasses.replace(PlanConfig(), time_budget=3.0))
    assert time.process_time() - started < 1.0  # refused before any optimisation


@pytest.mark.parametrize(
    ("shoulder_xy", "nearest_m"),
    [
        # a disc of 0.2 m round the shoulder, kept 5 cm off a counter at x >= 0: the shoulder stands 0.25 m before it
        ((0.0, 0.0), 0.25),
        # the shoulder 0.1 m ahead of the disc's centre: facing the counter, it stands 0.15 m before it
        ((0.1, 0.0), 0.15),
    ],
)
def test_a_handle_over_a_counter_is_out_of_reach_only_from_every_clear_base_pose(shoulder_xy, nearest_m) -> None:
    from funrec_robot.reach import floor_reach_gap
    from funrec_robot.robot_geometry import Circle
    from funrec_robot.scene import polygon_from_points

    counter = (polygon_from_points("counter", [[0.0, -1.0], [1.0, -1.0], [1.0, 1.0], [0.0, 1.0]]),)
    disc = (Circle(np.zeros(2), 0.2, (0.0, 0.8)),)
    wrist = np.array([0.3, 0.0, 1.5])  # 0.3 m over the counter, 0.5 m above the shoulder
    distance = float(np.hypot(0.3 + nearest_m, 0.5))  # 0.743 m and 0.673 m
    gap = floor_reach_gap(wrist, 1.0, np.array(shoulder_xy), disc, counter, distance - 0.03, 0.05)
    # a lower bound: at most the true 3 cm, and less by no more than the grid's and the heading step's slack (2 cm)
    assert gap is not None and 0.01 < gap <= 0.03 + 1e-9
    assert floor_reach_gap(wrist, 1.0, np.array(shoulder_xy), disc, counter, distance + 0.005, 0.05) is None
    assert floor_reach_gap(wrist, 1.0, np.array(shoulder_xy), disc, (), distance - 0.03, 0.05) is None  # no counter


@settings(deadline=None, max_examples=30)
@given(seed=st.integers(0, 2**31 - 1), roll=st.floats(-1.2, 1.2), axis=st.integers(0, 2))
def test_roll_to_hold_undoes_a_roll_about_the_axis(seed: int, roll: float, axis: int) -> None:
    R_held = Rotation.random(random_state=seed).as_matrix()
    R = R_held @ rotation_about_grasp_axis(axis, [roll])[0]
    back = roll_to_hold(R[None], R_held, axis, np.inf)[0]
    assert back == pytest.approx(-roll, abs=1e-9)
    clipped = roll_to_hold(R[None], R_held, axis, 0.5)[0]
    assert abs(clipped) <= 0.5 + 1e-12


def test_falls_to_follows_gravity_on_a_drop_down_door():
    """A door hinged at its bottom edge (axis x, opening towards -y) falls further open when let go part-way,
    never back closed; a spring stronger than gravity holds it."""
    import mujoco

    from funrec_robot.feasibility import falls_to

    door = """<mujoco><worldbody><body name="door" pos="0 0 0.1">
      <joint name="hinge" type="hinge" axis="1 0 0" range="0 1.5" stiffness="{k}"/>
      <geom type="box" pos="0 -0.01 0.3" size="0.25 0.01 0.3" mass="5"/></body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(door.format(k=0))
    assert falls_to(model, 0, 0.8, 1.45, 0.01)
    assert not falls_to(model, 0, 0.8, 0.1, 0.01)
    # gravity torque at most 5 * 9.81 * 0.3 = 14.7 N m; a 100 N m/rad spring about 0 wins everywhere past 0.15 rad
    held = mujoco.MjModel.from_xml_string(door.format(k=100))
    assert not falls_to(held, 0, 0.8, 1.45, 0.01)


def test_a_twins_friction_does_not_decide_whether_a_drop_down_door_falls():
    """funrec's export gives a twin's joint 1.5 times its largest gravity load as friction, so the door holds
    where it is let go; the plan judges the fall on gravity alone (PlanConfig.fall_ignores_friction)."""
    import mujoco

    from funrec_robot.feasibility import falls_to

    # gravity torque at most 5 * 9.81 * 0.3 = 14.7 N m; 1.5 times that as friction
    door = mujoco.MjModel.from_xml_string("""<mujoco><worldbody><body name="door" pos="0 0 0.1">
      <joint name="hinge" type="hinge" axis="1 0 0" range="0 1.5" frictionloss="22.1"/>
      <geom type="box" pos="0 -0.01 0.3" size="0.25 0.01 0.3" mass="5"/></body></worldbody></mujoco>""")
    assert not falls_to(door, 0, 0.8, 1.45, 0.01)
    assert falls_to(door, 0, 0.8, 1.45, 0.01, friction=False)
    assert not falls_to(door, 0, 0.8, 0.1, 0.01, friction=False)
    assert PlanConfig().fall_ignores_friction


@pytest.mark.parametrize(("friction", "expected"), [
    (0.0, 1.5),  # its weight carries it from 3 deg short to its stop: opened to the stop
    (22.1, 1.5 - np.deg2rad(3.0)),  # friction (1.5 times its largest gravity torque) holds it: the end margin stays
])
def test_open_takes_a_part_its_weight_carries_to_its_stop_all_the_way(friction: float, expected: float) -> None:
    """'open' and 'close' stop ``end_margin`` short of a range end, except where the part's weight carries it from
    there to the end (a drop-down door): held short, the door ran to its stop under Spot's hand and turned it about
    the bar."""
    from funrec_robot.plan import _requested_states
    from funrec_robot.task import ArticulationTask

    model = mujoco.MjModel.from_xml_string(f"""<mujoco><worldbody><body name="door" pos="0 0 0.1">
      <joint name="hinge" type="hinge" axis="1 0 0" range="0 1.5" frictionloss="{friction}"/>
      <geom type="box" pos="0 -0.01 0.3" size="0.25 0.01 0.3" mass="5"/></body></worldbody></mujoco>""")
    task = ArticulationTask(part="door", joint_type="revolute", axis_world=[1, 0, 0], pivot_world=[0.0, 0.0, 0.1],
                            state_range=(0.0, 1.5), state_current=0.0, p_world_contact=[0.0, -0.05, 0.6],
                            approach_world=[0, 1, 0], handle_axis_world=[1, 0, 0])
    states, _, target_state, _, blocked = _requested_states(task, model, 0, "open", None, PlanConfig())
    assert blocked is None
    assert target_state == pytest.approx(expected, abs=1e-9) and states[-1] == pytest.approx(expected, abs=1e-9)
    # where the arm does not reach the stop, the planner asks for the margin again (plan._handle_path)
    short = _requested_states(task, model, 0, "open", None, PlanConfig(), to_stop=False)[2]
    assert short == pytest.approx(1.5 - np.deg2rad(3.0), abs=1e-9)


def test_the_approach_tested_for_collisions_is_the_one_the_plan_moves_along(robot, revolute) -> None:
    """Ruckig synchronises the joints in time, not along one line: the collision test must sample the move at
    the limits the plan is timed with (at the robot's full limits TIAGo's arm missed a knob it then swept
    through). The plan's first approach move, to the pre-grasp pose where it dwells, is the tested one to 1e-9."""
    from funrec_robot.whole_body import _approach_samples

    gt, model, task, plan = revolute
    approach = plan.segment("approach")
    q = plan.q[approach.start : approach.end + 1]
    still = np.flatnonzero(np.all(np.abs(plan.qd[approach.start : approach.end + 1]) < 1e-12, axis=1))
    dwell = still[still > 0][0]  # the first sample at rest after the start: the pre-grasp (or via) pose
    samples = _approach_samples(robot, model, q[0], q[dwell], PlanConfig())
    assert len(samples) == dwell + 1
    assert np.abs(samples - q[: dwell + 1]).max() < 1e-9


def test_approach_touches_nothing_not_even_the_handle(robot, revolute) -> None:
    """Until the grasp closes, the open gripper touches no scene geom, the handle included (a swing through it
    would push the door before the grasp): kinematic replay of the approach, every sample."""
    gt, model, task, plan = revolute
    indices = robot_indices(robot, model)
    robot_geoms = set(bodies_geoms(model, indices.bodies).tolist())
    scene = np.flatnonzero(~np.isin(model.geom_bodyid, indices.bodies))
    floor = set(floor_geoms(model, scene).tolist())
    data = mujoco.MjData(model)
    approach = plan.segment("approach")
    touched = []
    for i in range(approach.start, approach.end + 1):
        data.qpos[:] = model.qpos0
        data.qpos[indices.qpos] = plan.q[i]
        data.qpos[indices.held_qpos] = indices.held_values
        data.qpos[indices.gripper_qpos] = plan.gripper_command[i]
        data.qpos[model.jnt_qposadr[part_joint(model, "part_0")]] = plan.part_state[i]
        mujoco.mj_forward(model, data)
        touched += [
            (float(plan.t[i]), model.geom(c.geom1).name, model.geom(c.geom2).name)
            for c in data.contact[: data.ncon]
            if (c.geom1 in robot_geoms) != (c.geom2 in robot_geoms) and not {c.geom1, c.geom2} & floor
        ]
    assert touched == []


def test_a_bar_laid_along_the_fingers_meets_the_palm(scenes) -> None:
    """The palm check: a vertical bar 1 cm ahead of the grasp frame, gripper pitched about the finger axis.
    Untilted the bar runs across the fingers, clear of the palm (which starts 4 cm behind the grasp frame on
    funrec_mm); pitched 1 rad or more it runs into the palm within the checked 15 cm either side."""
    from funrec_robot.grasp import GraspConfig, _bar_meets_palm
    from funrec_robot.robot_geometry import measure_robot

    geometry = measure_robot(load_robot(default_robot_path()))
    door = task_from_ground_truth(scenes[REVOLUTE_CASE], "part_0")
    config = GraspConfig()
    assert len(geometry.palm_corners) > 0 and geometry.palm_corners[:, 2].max() < 0.0
    for pitch, meets in ((0.0, False), (0.3, False), (1.0, True), (np.pi / 2, True)):
        R = rotation_about_grasp_axis(1, [pitch])[0]
        assert _bar_meets_palm(door, geometry, 0.01, R, config) is meets, pitch
    knob = dataclasses.replace(door, handle_axis_world=None)
    assert not _bar_meets_palm(knob, geometry, 0.01, rotation_about_grasp_axis(1, [np.pi / 2])[0], config)


def test_every_planning_stage_stops_at_the_time_limit(robot, revolute) -> None:
    """Limits cut at several fractions of the plan's own CPU time: each attempt fails within 0.5 s CPU of its
    limit, naming the stage that was running (the handle path, the search, IK, placement or timing)."""
    from funrec_robot.budget import check_time_limit, plan_time_limit
    from funrec_robot.feasibility import first_blocked_state

    gt, model, task, plan = revolute
    full = float(plan.provenance["plan_cpu_time_s"])
    stages = {}
    for fraction in (0.0, 0.1, 0.3, 0.5, 0.7, 0.9):
        limit = max(fraction * full, 1e-4)
        started = time.process_time()
        config = dataclasses.replace(PlanConfig(), time_limit=limit)
        try:
            plan_interaction(robot, gt / "scene.xml", task, "open", config=config, model=model)
        except PlanningError as exc:
            assert f"planning time limit of {limit:g} s CPU spent during " in str(exc), exc
            stages[fraction] = str(exc).split("spent during ")[1].split(";")[0]
        else:
            stages[fraction] = "finished"  # a second run may be faster than the first (caches)
        assert time.process_time() - started < limit + 0.5, (fraction, limit, stages)
    print(full, stages)
    assert len({s for s in stages.values() if s != "finished"}) >= 2, stages
    with plan_time_limit(0.0), pytest.raises(PlanningError, match="during the handle path"):
        first_blocked_state(model, part_joint(model, task.part), 0.0, 1.0, 0.01)
    check_time_limit("anything")  # outside a plan there is no limit
    with pytest.raises(PlanningError, match="time limit nan: expected a finite number"):
        plan_interaction(robot, gt / "scene.xml", task, "open", config=dataclasses.replace(PlanConfig(), time_limit=float("nan")))
