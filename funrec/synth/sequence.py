"""Generate one synthetic sequence: sample the scene, plan the motion, render every frame and
write the capture folder (FORMATS.md section 1) with its ground truth in gt/ (section 4).

The sequence is written into a hidden temporary sibling folder and renamed into place when
complete, so an interrupted run never leaves a folder that looks finished.
"""

from __future__ import annotations

import dataclasses
import logging
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from funrec.errors import FunrecError
from funrec.formats.camera_poses import write_camera_poses
from funrec.formats.capture import CaptureIntrinsics, CaptureWriter, write_mask
from funrec.formats.ground_truth import GroundTruthPart, write_ground_truth_json
from funrec.formats.twin import make_part
from funrec.synth.hand import SLEEVE_MATERIAL, forearm_geoms, hand_geoms, skin_color, with_sleeve
from funrec.synth.layout import sample_layout
from funrec.synth.mjcf import CAMERA_NAME, HAND_BODIES, TEXTURE_DIR, RenderRig, scene_to_mjcf
from funrec.synth.motion import Motion, plan_motion
from funrec.synth.part_geometry import PartGeometry
from funrec.synth.points import SurfaceAccumulator, write_ply
from funrec.synth.render import (
    R_MUJOCO_OPENCV,
    OffscreenRenderer,
    ensure_gl_backend,
    fovy_for_focal,
    intrinsics_from_fovy,
)
from funrec.synth.room import light_schedule
from funrec.synth.scene import Body, Front, Geom, Material, Scene, map_bodies
from funrec.synth.sensor import SensorNoise, noisy_depth, noisy_rgb
from funrec.synth.spec import SequenceSpec

if TYPE_CHECKING:
    import mujoco

LOGGER = logging.getLogger(__name__)

FOCAL_AT_480_PX = 525.0
"""Kinect-like focal length at 480 rows, pixels; scaled with the image height."""
GENERATOR_VERSION = 2
"""Bumped whenever the same spec would produce different files (2: bench families and
appearances; the spec in gt.json names its family)."""


@dataclass(frozen=True)
class SequencePlan:
    """Everything decided about a sequence before rendering."""

    spec: SequenceSpec
    """The sequence."""
    scene: Scene
    """The scene with the ground-truth joints named part_0, part_1, ... (others welded)."""
    fronts: tuple[Front, ...]
    """fronts[k] is part_k."""
    parts: tuple[PartGeometry, ...]
    """Geometry of each part at its canonical state (world frame)."""
    motion: Motion
    """Camera, joint and hand trajectories."""
    scene_xml: str
    """The scene as MJCF (textures under textures/ relative to the file)."""
    assets: dict[str, bytes]
    """Texture PNG files keyed by their path relative to scene.xml."""


def _find_body(bodies: tuple[Body, ...], name: str) -> Body:
    for body in bodies:
        if body.name == name:
            return body
        try:
            return _find_body(body.bodies, name)
        except KeyError:
            pass
    raise KeyError(name)


def _part_geometry(
    scene: Scene, model: mujoco.MjModel, data: mujoco.MjData, names: tuple[str, ...], fronts: tuple[Front, ...]
) -> tuple[PartGeometry, ...]:
    """Geometry of each part at qpos = 0, read from the compiled scene (world frame)."""
    import mujoco

    parts = []
    for name, front in zip(names, fronts):
        joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        body = _find_body(scene.bodies, front.body)
        body_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, front.body)
        panel = body.geoms[0]  # every front builder puts its panel first (or describes it)
        if front.panel is not None:
            panel = Geom("box", front.panel[1], front.panel[0], panel.material)
        R_world_body = data.xmat[body_id].reshape(3, 3)
        p_world_body = data.xpos[body_id]
        handle = data.site_xpos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, front.handle_site)].copy()
        handle_in_body = np.asarray(dict(body.sites)[front.handle_site])
        # Fronts face -y in their body frame; the panel's outer face is at pos_y - half_y.
        standoff = (panel.pos[1] - panel.size[1]) - handle_in_body[1]
        revolute = model.jnt_type[joint] == mujoco.mjtJoint.mjJNT_HINGE
        parts.append(
            PartGeometry(
                joint_type="revolute" if revolute else "prismatic",
                axis=data.xaxis[joint].copy(),
                pivot=data.xanchor[joint].copy() if revolute else None,
                upper=float(model.jnt_range[joint][1]),
                handle=handle,
                grip_axis=R_world_body @ np.asarray(front.grip_axis),
                centre=R_world_body @ np.asarray(panel.pos) + p_world_body,
                normal=R_world_body @ np.array([0.0, -1.0, 0.0]),
                width=float(2 * panel.size[0]),
                handle_standoff=float(standoff),
            )
        )
    return tuple(parts)


def _png(image: np.ndarray) -> bytes:
    ok, encoded = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    if not ok:
        raise FunrecError("cannot encode a texture as PNG")
    return encoded.tobytes()


def _geom_labels(model: mujoco.MjModel, part_bodies: tuple[str, ...]) -> np.ndarray:
    """(ngeom + 1,) label per geom id (last entry for id -1): 0 static, k + 1 part k, -1 hand."""
    import mujoco

    body_label = np.zeros(model.nbody, np.int32)
    for k, name in enumerate(part_bodies):
        body_label[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)] = k + 1
    for name in HAND_BODIES:
        body_label[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)] = -1
    return np.append(body_label[model.geom_bodyid], -1)


def _render_frames(
    plan: SequencePlan, root: Path, rng: np.random.Generator, progress: Callable[[int, int], None] | None
) -> SurfaceAccumulator:
    """Render, add sensor noise and write every frame; returns the accumulated true surface."""
    import mujoco

    spec, motion, parts = plan.spec, plan.motion, plan.parts
    names = tuple(f"part_{k}" for k in range(len(parts)))
    fovy = fovy_for_focal(spec.height, FOCAL_AT_480_PX * spec.height / 480.0)
    K = intrinsics_from_fovy(spec.width, spec.height, fovy)
    rig = RenderRig(
        spec.width,
        spec.height,
        fovy,
        hand_geoms("skin"),
        forearm_geoms("skin", spec.arm, SLEEVE_MATERIAL),
        Material("skin", skin_color(rng), specular=0.1, shininess=0.1),
    )
    model = mujoco.MjModel.from_xml_string(scene_to_mjcf(plan.scene, rig), plan.assets)
    data = mujoco.MjData(model)
    qpos = [model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in names]
    mocap = {
        name: model.body_mocapid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)]
        for name in ("camera_rig", *HAND_BODIES)
    }
    labels_of = _geom_labels(model, tuple(f.body for f in plan.fronts))
    intrinsics = CaptureIntrinsics(K.width, K.height, K.fx, K.fy, K.cx, K.cy, depth_scale=1000.0, fps=spec.fps)
    writer = CaptureWriter(root, intrinsics)
    gt = root / "gt" / "masks"
    # Pixel spacing stays under the voxel size at 1 m with every 2nd pixel of a 640x480 image.
    surface = SurfaceAccumulator(len(parts), stride=max(1, round(min(spec.width, spec.height) / 240)))
    noise = SensorNoise()
    poses = {"camera_rig": motion.T_world_camera, "hand": motion.T_world_grasp, "forearm": motion.T_world_forearm}
    T_parts = (
        np.stack([p.poses(motion.states[k]) for k, p in enumerate(parts)], axis=1)
        if parts
        else np.zeros((spec.num_frames, 0, 4, 4))
    )
    quat = np.empty(4)
    diffuse = model.light_diffuse.copy()
    light_scale = light_schedule(spec.lighting, model.nlight, spec.num_frames, rng)
    with OffscreenRenderer(model, spec.width, spec.height, CAMERA_NAME) as renderer:
        for f in range(spec.num_frames):
            model.light_diffuse[:] = diffuse * light_scale[f][:, None]
            for k, address in enumerate(qpos):
                data.qpos[address] = motion.states[k, f]
            for name, T in poses.items():
                R = T[f, :3, :3] @ R_MUJOCO_OPENCV if name == "camera_rig" else T[f, :3, :3]
                mujoco.mju_mat2Quat(quat, np.ascontiguousarray(R).ravel())
                data.mocap_pos[mocap[name]] = T[f, :3, 3]
                data.mocap_quat[mocap[name]] = quat
            mujoco.mj_forward(model, data)
            view = renderer.render(data)
            labels = labels_of[view.geom_id]
            hand = (view.geom_id >= 0) & (labels < 0)
            depth = noisy_depth(view.depth_m, rng, noise, exact=not spec.noise)
            rgb = noisy_rgb(view.rgb, rng, noise) if spec.noise else view.rgb
            writer.write_frame(f, rgb, depth, hand_mask=hand if spec.hand_masks else None)
            stem = f"{f:06d}.png"
            write_mask(gt / "hand" / stem, hand)
            for k, name in enumerate(names):
                mask = labels == k + 1
                if mask.any():
                    write_mask(gt / name / stem, mask)
            surface.add_frame(view.depth_m, labels, K.K, motion.T_world_camera[f], T_parts[f])
            if progress is not None:
                progress(f + 1, spec.num_frames)
    return surface


def _write_ground_truth(plan: SequencePlan, model: mujoco.MjModel, surface: SurfaceAccumulator | None, gt: Path) -> None:
    """Write points (none without a rendered ``surface``), camera poses and (last) gt.json."""
    import mujoco

    spec, motion, parts, fronts = plan.spec, plan.motion, plan.parts, plan.fronts
    names = tuple(f"part_{k}" for k in range(len(parts)))
    if surface is not None:
        write_ply(gt / "points" / "static.ply", surface.static.points())
        for name, cloud in zip(names, surface.parts):
            write_ply(gt / "points" / f"{name}.ply", cloud.points())
    write_camera_poses(gt / "camera_poses.txt", motion.T_world_camera)
    frames = np.arange(spec.num_frames)
    rows = []
    for k, (name, part) in enumerate(zip(names, parts)):
        joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        lower, upper = (float(v) for v in model.jnt_range[joint])
        articulated = make_part(
            name,
            part.joint_type,
            part.axis,
            part.pivot,
            frames,
            motion.states[k],
            (lower, upper),
            mesh=f"points/{name}.ply",
            masks=f"masks/{name}",
        )
        rows.append(GroundTruthPart(articulated, part.handle, motion.intervals[k]))
    part_info = [
        {"name": name, "kind": front.kind, "body": front.body, **front.details} for name, front in zip(names, fronts)
    ]
    extra = {
        "part_info": part_info,
        "scene": dict(plan.scene.description),
        "camera": {
            "convention": "opencv",
            "fovy_deg": fovy_for_focal(spec.height, FOCAL_AT_480_PX * spec.height / 480.0),
        },
        "generator": {
            "name": "funrec.synth",
            "version": GENERATOR_VERSION,
            "mujoco": mujoco.__version__,
            "spec": dataclasses.asdict(spec),
            "sensor_noise": dataclasses.asdict(SensorNoise()) if spec.noise else None,
        },
    }
    # gt.json goes last: its presence marks a complete sequence.
    write_ground_truth_json(gt / "gt.json", spec.num_frames, tuple(rows), np.eye(4), extra)


def plan_sequence(spec: SequenceSpec, texture_px: int | None = None) -> SequencePlan:
    """Sample the scene, compile it and plan the motion (no rendering).

    Args:
        spec: the sequence.
        texture_px: texture resolution (default: 512, or 128 below 240 rows); it does not
            change the layout or the motion.
    """
    ensure_gl_backend()
    import mujoco

    # Independent streams: switching the noise off leaves the scene and the motion unchanged.
    scene_rng, motion_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(spec.seed).spawn(2))
    if texture_px is None:
        texture_px = 512 if min(spec.width, spec.height) >= 240 else 128
    layout = sample_layout(spec.scene, spec.parts, scene_rng, texture_px, spec.appearance, spec.lighting, spec.layout)
    names = tuple(f"part_{k}" for k in range(len(spec.parts)))
    joint_names = {front.joint: name for front, name in zip(layout.targets, names)}
    scene = dataclasses.replace(layout.scene, bodies=map_bodies(layout.scene.bodies, joint_names))
    if spec.arm == "sleeve":
        scene = with_sleeve(scene, np.random.default_rng(np.random.SeedSequence(spec.seed).spawn(4)[3]), texture_px)
    assets = {f"{TEXTURE_DIR}/{t.name}.png": _png(t.image) for t in scene.textures} | dict(scene.mesh_files)
    scene_xml = scene_to_mjcf(scene, model_name=spec.name)
    model = mujoco.MjModel.from_xml_string(scene_xml, assets)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    parts = _part_geometry(scene, model, data, names, layout.targets)
    handles = np.array(
        [data.site_xpos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f.handle_site)] for f in scene.fronts]
    )
    motion = plan_motion(spec, parts, handles, scene.walk_area, motion_rng)
    return SequencePlan(spec, scene, layout.targets, parts, motion, scene_xml, assets)


def generate_sequence(
    spec: SequenceSpec, out_dir: Path, progress: Callable[[int, int], None] | None = None, scenes_only: bool = False
) -> Path:
    """Render one sequence into ``out_dir / spec.name`` (capture folder plus gt/).

    Args:
        spec: what to generate; the same spec always gives the same files.
        out_dir: parent folder (created if missing); an existing sequence of the same name
            is replaced once the new one is complete.
        progress: called as progress(frames_done, frames_total) after each frame.
        scenes_only: write only gt/ without its points and masks (scene.xml, textures, camera poses,
            gt.json): the true scene ``funrec-robot bench`` plans in, in seconds instead of minutes; no frames.

    Returns:
        The sequence folder.
    """
    import mujoco

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    plan = plan_sequence(spec)
    render_rng = np.random.default_rng(np.random.SeedSequence(spec.seed).spawn(3)[2])
    temp = Path(tempfile.mkdtemp(prefix=f".{spec.name}.", suffix=".partial", dir=out_dir))
    try:
        gt = temp / "gt"
        (gt / TEXTURE_DIR).mkdir(parents=True)
        for path, data in plan.assets.items():
            (gt / path).parent.mkdir(parents=True, exist_ok=True)
            (gt / path).write_bytes(data)
        (gt / "scene.xml").write_text(plan.scene_xml)
        model = mujoco.MjModel.from_xml_path(str(gt / "scene.xml"))  # the written file must load on its own
        surface = None if scenes_only else _render_frames(plan, temp, render_rng, progress)
        _write_ground_truth(plan, model, surface, gt)
        final = out_dir / spec.name
        if final.exists():
            trash = Path(tempfile.mkdtemp(prefix=f".{spec.name}.", suffix=".old", dir=out_dir))
            final.rename(trash / spec.name)
            temp.rename(final)
            shutil.rmtree(trash, ignore_errors=True)
        else:
            temp.rename(final)
    except BaseException:
        shutil.rmtree(temp, ignore_errors=True)
        raise
    LOGGER.info("wrote %s (%d frames)", final, spec.num_frames)
    return final


def is_complete(path: Path, scenes_only: bool = False) -> bool:
    """True if ``path`` holds a finished sequence (gt/gt.json is written last), or with ``scenes_only`` at least
    its ground-truth scene."""
    return (Path(path) / "gt" / "gt.json").is_file() and (scenes_only or (Path(path) / "intrinsics.json").is_file())


__all__ = ["FOCAL_AT_480_PX", "GENERATOR_VERSION", "SequencePlan", "generate_sequence", "is_complete", "plan_sequence"]
