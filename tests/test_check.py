"""Checking plans in MuJoCo: plans on ground truth pass (revolute through the CLI, prismatic through the API),
an infeasible target fails on the right criterion, and a plan made on a perturbed model still passes thanks to
the compliant controller."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from funrec_robot import build_mujoco_model, default_robot_path, load_robot, reset_to_home, robot_indices
from funrec_robot.check import CRITERIA, CheckConfig, check_plan
from funrec_robot.cli import EXIT_CHECK_FAILED, main
from funrec_robot.controller import Admittance, AdmittanceConfig, ServoModel
from funrec_robot.plan import plan_interaction
from funrec_robot.plan_file import read_plan, sha256_file
from funrec_robot.task import ArticulationTask
from funrec_robot.task_sources import task_from_ground_truth
from tests.helpers.robot_scenes import PRISMATIC_CASE, REVOLUTE_CASE, write_gt_scene

AXIS_ERROR_DEG = 3.0
"""Axis error of the perturbed model (a reconstructed twin is off by a few degrees)."""
PIVOT_ERROR_M = 0.03
"""Pivot error of the perturbed model, m."""


@pytest.fixture(scope="module")
def robot():
    return load_robot(default_robot_path())


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("check_scenes")
    return {name: write_gt_scene(name, root) for name in (REVOLUTE_CASE, PRISMATIC_CASE)}


def _plan(robot, gt: Path, task: ArticulationTask | None = None, target: str | float = "open"):
    model = build_mujoco_model(robot, gt / "scene.xml")
    task = task_from_ground_truth(gt, "part_0", model) if task is None else task
    return plan_interaction(robot, gt / "scene.xml", task, target, model=model)


def test_revolute_plan_and_check_pass_through_the_cli(scenes, tmp_path, capsys) -> None:
    gt = scenes[REVOLUTE_CASE]
    plan_path, video = tmp_path / "plan.json", tmp_path / "check.gif"
    assert main(["plan", "--scene", str(gt), "--part", "part_0", "--to", "open", "-o", str(plan_path)]) == 0
    assert main(["check", str(plan_path), "--gt", str(gt), "--video", str(video), "--video-fps", "1"]) == 0
    out = capsys.readouterr().out
    assert "PASS" in out and video.stat().st_size > 0
    record = json.loads(plan_path.with_suffix(".check.json").read_text())
    report, attested = record["report"], record["attested"]
    assert report["passed"] and report["failed_criteria"] == []
    assert report["target_error"] < np.deg2rad(5.0) and report["peak_handle_force_N"] <= 50.0
    # the signed record attests the plan, robot and scene by hash and every criterion with threshold and value
    assert attested["plan_sha256"] == sha256_file(plan_path) and attested["robot"]["sha256"] == sha256_file(default_robot_path())
    assert attested["scene"]["file"] == str((gt / "scene.xml").resolve()) and len(attested["scene"]["folder_sha256"]) == 64
    force = next(c for c in attested["criteria"] if c["name"] == "handle_force")
    assert force["threshold"] == 50.0 and force["measured"] == round(report["peak_handle_force_N"], 6) and force["passed"]
    assert {c["name"] for c in attested["criteria"]} == set(CRITERIA) and record["signature"]["algorithm"] == "ed25519"
    assert read_plan(plan_path).provenance["plan_time_s"] < 10.0


def test_prismatic_plan_and_check_pass(robot, scenes, monkeypatch) -> None:
    """Also: the grasp attachment lets go only once the opening fingers are clear of the handle (or at the
    end of the release segment), never while a pad still overlaps it."""
    from funrec_robot import check

    clear_at: dict[float, bool] = {}
    attached_at: list[tuple[float, bool]] = []
    is_clear, wrench = check._Execution._gripper_clear_of_part, check._Execution._handle_wrench

    def spy_clear(self):
        clear_at[round(self.data.time, 6)] = result = is_clear(self)
        return result

    def spy_wrench(self, attached):
        attached_at.append((round(self.data.time, 6), attached))
        return wrench(self, attached)

    monkeypatch.setattr(check._Execution, "_gripper_clear_of_part", spy_clear)
    monkeypatch.setattr(check._Execution, "_handle_wrench", spy_wrench)
    gt = scenes[PRISMATIC_CASE]
    plan = _plan(robot, gt)
    report = check_plan(plan, robot, gt / "scene.xml")
    assert report.passed, report.failures
    release = plan.segment("release")
    let_go = [t for (t0, a0), (t, a1) in zip(attached_at, attached_at[1:]) if a0 and not a1]
    assert len(let_go) == 1 and let_go[0] >= release.t_start
    assert clear_at.get(let_go[0]) is True or let_go[0] >= release.t_end
    assert report.grasp_engaged_time is not None and report.collisions == ()
    assert report.target_error < 0.02 and report.max_velocity_ratio <= 1.1


def test_infeasible_target_fails_on_the_target_criterion(robot, scenes, tmp_path) -> None:
    """A model whose range overshoots the real one (the drawer stops at 0.433 m) cannot reach 0.53 m."""
    gt = scenes[PRISMATIC_CASE]
    task = task_from_ground_truth(gt, "part_0")
    stretched = dataclasses.replace(task, state_range=(0.0, 0.6))
    plan = _plan(robot, gt, stretched, 0.53)
    report = check_plan(plan, robot, gt / "scene.xml")
    failed = {f.criterion for f in report.failures}
    assert not report.passed and "target" in failed and failed <= set(CRITERIA)
    target = next(f for f in report.failures if f.criterion == "target")
    assert "part_0" in target.detail and report.final_state < 0.44


def test_cli_check_exits_3_on_failure(robot, scenes, tmp_path) -> None:
    gt = scenes[PRISMATIC_CASE]
    plan_path = tmp_path / "plan.json"
    assert main(["plan", "--scene", str(gt), "--to", "0.3", "-o", str(plan_path)]) == 0
    # Judged against an impossible force bound, the same plan fails.
    assert main(["check", str(plan_path), "--max-handle-force", "0.01"]) == EXIT_CHECK_FAILED
    report = json.loads(plan_path.with_suffix(".check.json").read_text())["report"]
    assert "handle_force" in report["failed_criteria"]


def _perturbed(task: ArticulationTask, rng: np.random.Generator) -> ArticulationTask:
    """The task with its axis turned by AXIS_ERROR_DEG about a random perpendicular through the axis point
    level with the handle (where a twin's estimate is anchored: the observed motion) and its pivot moved
    PIVOT_ERROR_M across the axis: what a reconstructed twin would hand the planner."""
    perpendicular = np.cross(task.axis_world, rng.normal(size=3))
    perpendicular /= np.linalg.norm(perpendicular)
    R = Rotation.from_rotvec(np.deg2rad(AXIS_ERROR_DEG) * perpendicular).as_matrix()
    shift = np.cross(task.axis_world, rng.normal(size=3))
    shift *= PIVOT_ERROR_M / np.linalg.norm(shift)
    pivot = None
    if task.pivot_world is not None:
        anchor = task.pivot_world + task.axis_world * float(task.axis_world @ (task.p_world_contact - task.pivot_world))
        pivot = anchor + shift
    return dataclasses.replace(task, axis_world=R @ task.axis_world, pivot_world=pivot)


def test_plan_on_a_perturbed_model_passes_in_the_true_scene(robot, scenes) -> None:
    gt = scenes[REVOLUTE_CASE]
    task = _perturbed(task_from_ground_truth(gt, "part_0"), np.random.default_rng(3))
    plan = _plan(robot, gt, task)
    report = check_plan(plan, robot, gt / "scene.xml")
    assert report.passed, report.failures
    assert report.peak_handle_force <= 50.0


@pytest.mark.slow
def test_compliance_is_what_absorbs_the_model_error(robot, scenes) -> None:
    """Without the admittance law the same perturbed plan fights the real hinge with more force."""
    gt = scenes[REVOLUTE_CASE]
    task = _perturbed(task_from_ground_truth(gt, "part_0"), np.random.default_rng(3))
    plan = _plan(robot, gt, task)
    compliant = check_plan(plan, robot, gt / "scene.xml")
    rigid = check_plan(plan, robot, gt / "scene.xml", config=dataclasses.replace(CheckConfig(), compliant=False))
    assert rigid.peak_handle_force > compliant.peak_handle_force


ADMITTANCE_TRACKING_TOL_M = 0.002
"""Largest gap between the grasp offset the admittance wants and the one its joint offsets realise while the
plan swings the arm, m: one Gauss-Newton step per 2 ms tick against a reference moving ~2 mrad per tick leaves
a residual of second order (measured 1.4e-6 m); joint offsets integrated once and carried along (the law before
this test) drift by 50 mm and 0.13 rad over this swing."""
ADMITTANCE_TRACKING_TOL_RAD = 0.01
"""The same for the rotational offset, rad."""


def test_admittance_offset_stays_cartesian_while_the_arm_swings(robot) -> None:
    """The twin plan of rev_double_door_00 swung arm joints 1 and 3 by 1.3 rad each while holding the door; joint
    offsets computed once with the Jacobian of an earlier configuration then moved the hand 6 cm back along the
    path and stalled the door. The offset must stay the Cartesian one the admittance wants."""
    model = build_mujoco_model(robot)
    data = mujoco.MjData(model)
    reset_to_home(robot, model, data)
    indices = robot_indices(robot, model)
    servos = ServoModel.of(model, indices.actuators)
    admittance = Admittance(model, indices.grasp_site, indices.dof, len(robot.base_joints), AdmittanceConfig(), servos)
    q_home = data.qpos[indices.qpos].copy()
    swing = np.zeros(robot.nq)
    swing[robot.joint_names.index("arm_joint1")], swing[robot.joint_names.index("arm_joint3")] = 1.0, -1.0
    wanted = np.array([0.0, 0.02, -0.04, 0.1, 0.0, 0.0])
    admittance.offset = wanted.copy()
    probe = mujoco.MjData(model)

    def site(q):
        probe.qpos[:] = data.qpos
        probe.qpos[indices.qpos] = q
        mujoco.mj_kinematics(model, probe)
        return probe.site_xpos[indices.grasp_site].copy(), probe.site_xmat[indices.grasp_site].reshape(3, 3).copy()

    for _ in range(20):  # settle on the offset at the start configuration
        admittance.update(data, q_home, np.zeros(6), 0.002, False)
    gaps = []
    for s in np.linspace(0.0, 1.0, 500):
        q_ref = q_home + s * swing
        q_offset = admittance.update(data, q_ref, np.zeros(6), 0.002, False)
        (p_ref, R_ref), (p_cmd, R_cmd) = site(q_ref), site(q_ref + q_offset)
        rotation = Rotation.from_matrix(R_cmd @ R_ref.T).as_rotvec()
        gaps.append((np.linalg.norm(p_cmd - p_ref - wanted[:3]), np.linalg.norm(rotation - wanted[3:])))
    gaps = np.array(gaps)
    assert gaps[:, 0].max() < ADMITTANCE_TRACKING_TOL_M, gaps[:, 0].max()
    assert gaps[:, 1].max() < ADMITTANCE_TRACKING_TOL_RAD, gaps[:, 1].max()


FETCH_PRISMATIC_CASE = "pri_drawer_03"
"""A drawer with a round bar at 0.94 m: Fetch can take it with its gripper pitched down."""


def _fetch():
    pytest.importorskip("gymnasium_robotics")
    from funrec_robot import resolve_robot

    return load_robot(resolve_robot("fetch"))


@pytest.mark.slow
def test_fetch_plans_and_passes_a_prismatic_case(tmp_path) -> None:
    fetch = _fetch()
    gt = write_gt_scene(FETCH_PRISMATIC_CASE, tmp_path)
    plan = _plan(fetch, gt)
    report = check_plan(plan, fetch, gt / "scene.xml")
    assert report.passed, report.failures


@pytest.mark.slow
@pytest.mark.xfail(
    reason="the gymnasium Fetch model's 4 kg fingers load its wrist: with robots/fetch.yaml's second posture the "
    "wrist holds them, but at the end of a door's arc the forearm roll needs ~2 % more than its 29.4 N m",
    strict=False,
)
def test_fetch_plans_and_passes_a_revolute_case(scenes) -> None:
    fetch = _fetch()
    gt = scenes[REVOLUTE_CASE]
    report = check_plan(_plan(fetch, gt), fetch, gt / "scene.xml")
    assert report.passed, report.failures


@pytest.mark.slow
def test_the_legitimate_path_runs_with_default_settings(scenes, tmp_path, capsys) -> None:
    """`check plan.json`, `serve-sim &`, `send plan.json --to 127.0.0.1:PORT`: no flags, keys made on first use
    (about the plan's duration in real time plus planning and checking: slow)."""
    import threading

    from funrec_robot.sim_server import SimServerConfig, make_sim_server

    gt = scenes[REVOLUTE_CASE]
    plan_path = tmp_path / "plan.json"
    assert main(["plan", "--scene", str(gt), "--part", "part_0", "--to", "open", "-o", str(plan_path)]) == 0
    assert main(["check", str(plan_path)]) == 0
    server = make_sim_server(load_robot(default_robot_path()), None, SimServerConfig(port=0))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        capsys.readouterr()
        assert main(["send", str(plan_path), "--to", f"127.0.0.1:{server.server_address[1]}"]) == 0
        assert capsys.readouterr().out.startswith("done: plan finished after")
    finally:
        server.shutdown()
        thread.join(5.0)
        server.server_close()


def test_a_grasp_point_far_from_every_piece_of_the_part_is_nothing_to_hold() -> None:
    """A twin's grasp point may land off every piece of the true part (geo_angled_rev_cabinet_00's twin at
    da881ad: 3.9 cm from the nearest): the check then has no handle geoms, and the distance to them is
    infinite (the grasp criterion fails with that distance), not a numpy ValueError out of the bench."""
    from funrec_robot.check import _point_box_distance

    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom type='box' size='.1 .1 .1'/></worldbody></mujoco>")
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    assert _point_box_distance(model, data, np.zeros(0, dtype=np.int64), np.zeros(3)) == float("inf")
    assert _point_box_distance(model, data, np.array([0]), np.array([0.3, 0.0, 0.0])) == pytest.approx(0.2)
