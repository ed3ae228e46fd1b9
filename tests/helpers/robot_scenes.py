"""Ground-truth scenes for the planning and robot tests, generated without rendering.

``funrec.synth.plan_sequence`` samples a bench sequence's scene and motion in under a second; this writes its
gt/ folder the way ``generate_sequence`` does (scene.xml with textures, camera_poses.txt, gt.json) minus the
rendered frames and points, so the scenes are exactly the bench's.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from funrec.formats.camera_poses import write_camera_poses
from funrec.formats.ground_truth import GroundTruthPart, write_ground_truth_json
from funrec.formats.twin import make_part
from funrec.synth.sequence import plan_sequence
from funrec.synth.suite import families_suite, reseeded

REVOLUTE_CASE = "rev_cabinet_left_00"
"""A cabinet door with a vertical bar handle, hinge on the left."""
PRISMATIC_CASE = "pri_drawer_00"
"""A drawer with a horizontal bar handle at 0.8 m."""


def write_gt_scene(name: str, out_dir: Path, reseed: int = 0) -> Path:
    """Write the gt/ folder of bench sequence ``name`` (of any family; its ``reseed``-th copy, named
    ``<name>_r<reseed>``, for ``reseed`` > 0) under ``out_dir/<its name>`` and return it."""
    spec = reseeded({s.name: s for s in families_suite()}[name], reseed)
    plan = plan_sequence(spec, texture_px=32)
    gt = Path(out_dir) / spec.name / "gt"
    for path, data in plan.assets.items():
        (gt / path).parent.mkdir(parents=True, exist_ok=True)
        (gt / path).write_bytes(data)
    (gt / "scene.xml").write_text(plan.scene_xml)
    write_camera_poses(gt / "camera_poses.txt", plan.motion.T_world_camera)
    model = mujoco.MjModel.from_xml_path(str(gt / "scene.xml"))
    frames = np.arange(spec.num_frames)
    rows = []
    for k, part in enumerate(plan.parts):
        joint = model.joint(f"part_{k}")
        lower, upper = (float(v) for v in joint.range)
        articulated = make_part(f"part_{k}", part.joint_type, part.axis, part.pivot, frames, plan.motion.states[k], (lower, upper))
        rows.append(GroundTruthPart(articulated, part.handle, plan.motion.intervals[k]))
    extra = {"generator": {"spec": {"fps": spec.fps}}}
    write_ground_truth_json(gt / "gt.json", spec.num_frames, tuple(rows), np.eye(4), extra)
    return gt
