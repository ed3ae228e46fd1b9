"""funrec-robot replay on a twin folder made from a bench scene's ground truth (a fixture: the twin is exact)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from funrec.errors import PlanningError
from funrec.formats.affordances import Affordances, Interaction, PartAffordance, write_affordances
from funrec.formats.ground_truth import read_ground_truth
from funrec.formats.twin import TwinArticulation, write_articulation
from funrec_robot import default_robot_path
from funrec_robot.check_record import require_passing_record
from funrec_robot.replay import demonstrated_interactions, replay_twin
from funrec_robot.task_sources import task_from_ground_truth
from tests.helpers.robot_scenes import PRISMATIC_CASE, write_gt_scene


def _twin_from_gt(gt_dir: Path, twin: Path) -> Path:
    """A twin folder holding the ground truth itself: articulation.json from gt.json, twin.xml = scene.xml
    (world = scene frame, T_scene_world is the identity here), affordances.json from the true handle and
    the scene's front geometry, the first demonstrated interval as the only hold."""
    gt = read_ground_truth(gt_dir)
    assert np.allclose(gt.T_scene_world, np.eye(4))
    shutil.copytree(gt_dir, twin)
    (twin / "twin.xml").write_text((gt_dir / "scene.xml").read_text())
    write_articulation(twin / "articulation.json", TwinArticulation(gt.frame_count, tuple(p.part for p in gt.parts)))
    rows = []
    for gt_part in gt.parts:
        task = task_from_ground_truth(gt_dir, gt_part.part.name)
        T_world_grasp = np.eye(4)
        x, z = task.handle_axis_world, task.approach_world
        T_world_grasp[:3, :3] = np.column_stack([x, np.cross(z, x), z])
        T_world_grasp[:3, 3] = task.p_world_contact
        first, last = gt_part.intervals[0]
        keep = (gt_part.part.frames >= first) & (gt_part.part.frames <= last)
        frames = gt_part.part.frames[keep]
        hold = Interaction(frames, frames / 15.0, gt_part.part.states[keep])
        rows.append(PartAffordance(gt_part.part.name, gt_part.part.joint_type, task.p_world_contact, T_world_grasp, True,
                                   (hold,), task.p_world_contact[None], np.ones(1), np.zeros(0), np.zeros((0, 3))))
    write_affordances(twin / "affordances.json", Affordances(tuple(rows), (), "capture", 15.0))
    return twin


@pytest.fixture(scope="module")
def twin(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("replay")
    gt = write_gt_scene(PRISMATIC_CASE, root)
    return _twin_from_gt(gt, root / "twin"), gt


def test_interactions_come_in_time_order_and_a_twin_without_holds_is_refused(twin, tmp_path) -> None:
    twin_dir, _ = twin
    holds = demonstrated_interactions(twin_dir)
    assert [h.part for h in holds] == ["part_0"] and holds[0].end_state > holds[0].start_state
    write_affordances(tmp_path / "affordances.json", Affordances((), (("part_0", "never held"),), "capture", 15.0))
    with pytest.raises(PlanningError, match=r"affordances\.json: no demonstrated interaction to replay \(part_0: never held\)"):
        demonstrated_interactions(tmp_path)


def test_replay_plans_and_checks_the_demonstration_in_the_true_scene(twin, tmp_path) -> None:
    twin_dir, gt = twin
    report = replay_twin(default_robot_path(), twin_dir, tmp_path, gt_dir=gt, video=False)
    step = report["steps"][0]
    assert report["interactions"] == 1 and step["joint"] == "part_0"
    assert report["all_passed"], step["failure"]
    require_passing_record(step["plan_file"])  # the record binds the plan's bytes: send would accept it
    assert json.loads((tmp_path / "replay.json").read_text())["passed"] == 1


def test_a_twin_whose_floor_is_not_the_scenes_is_refused(twin, tmp_path) -> None:
    """A twin that took a counter top for its floor would have the robot stand in the air of the true scene:
    its plans are refused there (before the fix such a plan passed its check with the base 0.9 m up)."""
    from types import SimpleNamespace

    from funrec.formats.camera_poses import read_camera_poses, write_camera_poses
    from funrec.formats.twin_gravity import TWIN_GRAVITY_FILE, TwinGravity, write_twin_gravity
    from funrec_robot.check import FLOOR_HEIGHT_TOLERANCE, T_scene_plan_from_gt

    twin_dir, gt = twin
    plan = SimpleNamespace(provenance={"task_source": f"twin:{twin_dir}"})
    assert np.allclose(T_scene_plan_from_gt(plan, gt), np.eye(4), atol=1e-9)
    lifted = tmp_path / "lifted"
    shutil.copytree(twin_dir, lifted)
    poses = read_camera_poses(lifted / "camera_poses.txt")
    T_world_camera = poses.T_world_camera.copy()
    T_world_camera[:, 2, 3] -= 0.9  # the twin's floor 0.9 m above the true one: the cameras 0.9 m lower in it
    write_camera_poses(lifted / "camera_poses.txt", T_world_camera, poses.frames)
    with pytest.raises(PlanningError, match=r"the twin's floor lies \+0\.90 m off the scene's.*was the floor seen"):
        T_scene_plan_from_gt(SimpleNamespace(provenance={"task_source": f"twin:{lifted}"}), gt)
    # A twin that says where its floor came from (gravity.json) is quoted.
    write_twin_gravity(lifted / TWIN_GRAVITY_FILE, TwinGravity("worktop_plane", "not seen: assumed 0.90 m below a worktop"))
    with pytest.raises(PlanningError, match=r"the twin says its floor was not seen: assumed 0\.90 m below a worktop"):
        T_scene_plan_from_gt(SimpleNamespace(provenance={"task_source": f"twin:{lifted}"}), gt)
    T_world_camera[:, 2, 3] += 0.9 - 0.8 * FLOOR_HEIGHT_TOLERANCE
    write_camera_poses(lifted / "camera_poses.txt", T_world_camera, poses.frames)
    T_scene_plan_from_gt(SimpleNamespace(provenance={"task_source": f"twin:{lifted}"}), gt)
