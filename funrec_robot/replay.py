"""Demo-to-robot replay: plan and check every interaction demonstrated in a twin, in the order the person
did them, and write one report and one video.

Each hold of affordances.json (``funrec-affordances/1``) is one interaction: the robot plans the
demonstrated joint trajectory of that part (``--to demo``) from the state the hold started at, and the
plan is checked in the twin (or, with ``gt_dir``, in the true scene of a synthetic capture, placed there
through camera 0 as in FORMATS.md section 4). Every check starts from the scene's reference configuration
with the part at the hold's starting state: a part opened by an earlier interaction is not carried over.
"""

from __future__ import annotations

import json
import logging
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from funrec.errors import FunrecError, PlanningError
from funrec.formats.staged_folder import write_text_staged
from funrec_robot.check import CheckConfig, T_scene_plan_from_gt, check_plan
from funrec_robot.check_record import write_check_record
from funrec_robot.plan import PlanConfig, plan_interaction
from funrec_robot.plan_file import write_plan
from funrec_robot.robot import load_robot
from funrec_robot.sim_model import build_mujoco_model
from funrec_robot.task_sources import task_from_twin

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DemoInteraction:
    """One demonstrated hold of a part."""

    part: str
    """Part name, as in articulation.json."""
    index: int
    """Index of the hold among the part's holds."""
    t_start: float
    """When the hold started, s from the capture's start."""
    start_state: float
    """The part's state when the hold started, rad or m."""
    end_state: float
    """Its state when the hold ended, rad or m."""


@dataclass(frozen=True)
class ReplayStep:
    """What became of one interaction."""

    interaction: DemoInteraction
    """The demonstrated interaction."""
    joint: str
    """Joint of the checked scene that was operated ('' if not planned)."""
    planned: bool
    """A plan was made."""
    passed: bool
    """The plan passed its check."""
    failure: str
    """The planning error or the failed criteria; '' if passed."""
    plan_file: str
    """plan.json written ('' if not planned)."""
    check_file: str
    """Check record written ('' if not planned)."""
    plan_time: float
    """Planning wall-clock time, s."""


def demonstrated_interactions(twin_dir: str | Path) -> tuple[DemoInteraction, ...]:
    """Every hold of every part in a twin's affordances.json, in time order.

    Raises:
        FormatError: missing or malformed affordances.json; PlanningError: no hold at all.
    """
    from funrec.query import load_affordances

    affordances = load_affordances(twin_dir)
    holds = [
        DemoInteraction(part.name, k, float(hold.times_s[0]), float(hold.states[0]), float(hold.states[-1]))
        for part in affordances.parts
        for k, hold in enumerate(part.interactions)
    ]
    if not holds:
        missing = "; ".join(f"{name}: {why}" for name, why in affordances.missing) or "no parts"
        raise PlanningError(f"{Path(twin_dir) / 'affordances.json'}: no demonstrated interaction to replay ({missing})")
    return tuple(sorted(holds, key=lambda h: (h.t_start, h.part)))


def nearest_gt_joint(gt_dir: Path, T_scene_twin: np.ndarray, p_twin_contact: np.ndarray) -> str:
    """The ground-truth part whose handle is nearest the twin's contact point (both in the scene's frame)."""
    from funrec.formats.ground_truth import read_ground_truth

    gt = read_ground_truth(gt_dir)
    p_scene = T_scene_twin[:3, :3] @ p_twin_contact + T_scene_twin[:3, 3]
    T = gt.T_scene_world
    distances = [float(np.linalg.norm(T[:3, :3] @ p.handle_world + T[:3, 3] - p_scene)) for p in gt.parts]
    return gt.parts[int(np.argmin(distances))].part.name


def _concatenate_videos(paths: list[Path], out: Path, fps: float) -> Path:
    import cv2

    from funrec_robot.video import write_video

    frames = []
    for path in paths:
        reader = cv2.VideoCapture(str(path))
        ok, frame = reader.read()
        while ok:
            frames.append(frame[..., ::-1].copy())  # BGR -> RGB
            ok, frame = reader.read()
        reader.release()
    return write_video(out, frames, fps)


def replay_twin(
    robot_path: str | Path,
    twin_dir: str | Path,
    out_dir: str | Path,
    gt_dir: str | Path | None = None,
    plan_config: PlanConfig | None = None,
    check_config: CheckConfig | None = None,
    video: bool = True,
    progress: Callable[[ReplayStep], None] | None = None,
) -> dict[str, Any]:
    """Plan and check every demonstrated interaction of a twin, in order.

    Writes ``out_dir/NN_PART_K.json`` plans with their ``.check.json`` records, ``out_dir/replay.json``
    (the returned report) and, with ``video``, ``out_dir/replay.mp4`` (the checks one after another).

    Args:
        robot_path: robot YAML file.
        twin_dir: twin folder with articulation.json, affordances.json and twin.xml.
        out_dir: output folder (created).
        gt_dir: check in this ground truth's scene.xml instead of the twin (synthetic captures).
        progress: called with each step as it is done.

    Raises:
        FormatError / PlanningError: unreadable twin or no interaction; a failing interaction is
        reported, not raised.
    """
    plan_config = PlanConfig() if plan_config is None else plan_config
    check_config = CheckConfig() if check_config is None else check_config
    twin_dir, out_dir = Path(twin_dir).resolve(), Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    robot = load_robot(robot_path)
    twin_xml = twin_dir / "twin.xml"
    model = build_mujoco_model(robot, twin_xml, textures=False)
    steps: list[ReplayStep] = []
    clips: list[Path] = []
    with tempfile.TemporaryDirectory(prefix="funrec_replay_") as scratch:
        for n, hold in enumerate(demonstrated_interactions(twin_dir)):
            stem = f"{n:02d}_{hold.part}_{hold.index}"
            clock = time.perf_counter()
            joint = ""
            try:
                task = task_from_twin(twin_dir, hold.part, state_current=hold.start_state, interaction=hold.index)
                plan = plan_interaction(robot, twin_xml, task, "demo", config=plan_config, model=model)
                plan_time = time.perf_counter() - clock
                plan_file = write_plan(out_dir / f"{stem}.json", plan)
                scene_xml, T_scene_plan, joint = twin_xml, None, hold.part
                if gt_dir is not None:
                    T_scene_plan = T_scene_plan_from_gt(plan, gt_dir)
                    scene_xml = Path(gt_dir) / "scene.xml"
                    joint = nearest_gt_joint(Path(gt_dir), T_scene_plan, task.p_world_contact)
                clip = Path(scratch) / f"{stem}.mp4" if video else None
                report = check_plan(plan, robot, scene_xml, joint, T_scene_plan, check_config, clip)
            except FunrecError as exc:
                step = ReplayStep(hold, joint, False, False, str(exc), "", "", time.perf_counter() - clock)
            else:
                record = write_check_record(report, plan_file, check_config)
                if clip is not None:
                    clips.append(clip)
                failure = "; ".join(f"{f.criterion} at {f.time:.2f} s: {f.detail}" for f in report.failures)
                step = ReplayStep(hold, joint, True, report.passed, failure, str(plan_file), str(record), plan_time)
            log.info("interaction %d (%s hold %d): %s", n, hold.part, hold.index, "pass" if step.passed else step.failure)
            steps.append(step)
            if progress is not None:
                progress(step)
        video_path = _concatenate_videos(clips, out_dir / "replay.mp4", check_config.video_fps) if clips else None
    report = {
        "format": "funrec-replay/1",
        "twin": str(twin_dir),
        "robot_file": str(robot.yaml_path),
        "scene": str(Path(gt_dir) / "scene.xml") if gt_dir is not None else str(twin_xml),
        "interactions": len(steps),
        "passed": sum(s.passed for s in steps),
        "all_passed": all(s.passed for s in steps),
        "video": None if video_path is None else str(video_path),
        "steps": [asdict(s) for s in steps],
    }
    write_text_staged(out_dir / "replay.json", json.dumps(report, indent=1) + "\n")
    return report


__all__ = ["DemoInteraction", "ReplayStep", "demonstrated_interactions", "replay_twin"]
