"""HOI4D annotations turned into FORMATS.md section 4 ground truth: per-frame part boxes (``objpose/N.json``),
camera poses (``3Dseg/output.log``) and the action segmentation (``action/color.json``).

HOI4D annotates each articulated part's pose as a box in the camera frame, not the joint; the joint of a moved
part is fitted here to the part's motion relative to the object's body. What HOI4D does not annotate (the handle,
a part's true surface) is approximated and named as such in gt.json's ``"hoi4d"`` entry.
"""

from __future__ import annotations

import ast
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from funrec.errors import CaptureError
from funrec.formats.ground_truth import GroundTruthPart
from funrec.formats.twin import make_part
from funrec.geometry.fitting import fit_prismatic_motions, fit_revolute_motions
from funrec.geometry.transforms import invert_transform, make_transform
from funrec.typed import FloatArray

BASE_LABELS = ("Lockerbody", "Safebox", "bucket", "Dustbinbase", "Laptopkeyboard")
"""objpose labels of the fixed body of HOI4D's articulated categories (StorageFurniture, Safe, Bucket, TrashCan,
Laptop); other objects use the part that moves least in the world, or the first listed."""
MIN_REVOLUTE_RAD = np.deg2rad(10.0)
"""A part whose rotation relative to the body spans more than this is revolute (HOI4D's box annotations wobble
by a few degrees, so a smaller span is annotation noise)."""
MIN_PRISMATIC_M = 0.03
"""A non-revolute part whose box centre moves more than this relative to the body is prismatic (box centres
wobble by about a centimetre)."""
INTERACTION_WORDS = ("open", "close", "pull", "push")
"""Action events whose name contains one of these (case-insensitive) are hand-part interactions."""
POINTS_PER_PART = 2000
"""Samples of the part box surface written to gt/points/part_k.ply."""


@dataclass(frozen=True)
class PartBoxes:
    """One labelled part's annotated boxes over the source frames."""

    label: str
    """objpose label, e.g. 'Lockerdrawer'."""
    T_camera_part: dict[int, FloatArray]
    """Source frame -> (4, 4) box pose (centre and orientation), camera frame, metres."""
    extents_m: FloatArray
    """(3,) box length, width, height along the box's x, y, z, metres (first annotation)."""


def _load_json_like(path: Path) -> Any:
    text = path.read_text()
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        pass
    try:  # some HOI4D files are Python literals (the official loader uses eval); literal_eval runs no code
        return ast.literal_eval(text)
    except (ValueError, SyntaxError) as exc:
        raise CaptureError(path, f"neither JSON nor a Python literal ({exc})") from None


def read_objpose(folder: Path) -> dict[str, PartBoxes]:
    """Part boxes of every labelled part in ``objpose/<frame>.json`` (HOI4D names them ``0.json`` or ``00000.json``).

    Each entry has ``center`` {x, y, z} (metres, camera frame), ``rotation`` {x, y, z} (intrinsic XYZ Euler
    angles, radians, as in HOI4D's ``read_rtd``) and ``dimensions`` {length, width, height}.
    """
    poses: dict[str, dict[int, FloatArray]] = {}
    extents: dict[str, FloatArray] = {}
    for path in sorted((p for p in folder.glob("*.json") if p.stem.isdigit()), key=lambda p: int(p.stem)):
        frame = int(path.stem)
        data = _load_json_like(path)
        entries = data.get("dataList", data.get("objects")) if isinstance(data, dict) else None
        if not isinstance(entries, list):
            raise CaptureError(path, "expected a 'dataList' (or 'objects') list of part boxes", frame)
        for k, entry in enumerate(entries):
            try:
                label = str(entry.get("label", f"part{k}"))
                c, r, d = entry["center"], entry["rotation"], entry["dimensions"]
                R = Rotation.from_euler("XYZ", [r["x"], r["y"], r["z"]]).as_matrix()
                poses.setdefault(label, {})[frame] = make_transform(R, [c["x"], c["y"], c["z"]])
                extents.setdefault(label, np.array([d["length"], d["width"], d["height"]], dtype=np.float64))
            except (KeyError, TypeError, AttributeError) as exc:
                raise CaptureError(path, f"dataList[{k}] lacks center/rotation/dimensions ({exc})", frame) from None
    return {label: PartBoxes(label, poses[label], extents[label]) for label in poses}


def read_trajectory(path: Path) -> list[FloatArray]:
    """Camera-to-world poses of ``3Dseg/output.log`` (Open3D/Redwood trajectory log: each block's matrix is
    the camera pose, T_world_camera; Open3D stores its inverse as the extrinsic)."""
    import open3d as o3d

    trajectory = o3d.io.read_pinhole_camera_trajectory(str(path))
    if not trajectory.parameters:
        raise CaptureError(path, "no camera pose in the trajectory log")
    return [invert_transform(np.asarray(p.extrinsic, dtype=np.float64)) for p in trajectory.parameters]


def read_interactions(path: Path, frame_count: int) -> tuple[list[tuple[int, int]], float | None]:
    """Source-frame spans of the interaction events in ``action/color.json``, and the video's duration.

    Two layouts occur: ``{"info": {"duration": s}, "events": [{"event", "startTime", "endTime"}]}`` and
    ``{"info": {"Duration": s}, "markResult": {"marks": [{"event", "hdTimeStart", "hdTimeEnd"}]}}``; times are
    seconds, turned into frames with ``frame_count / duration``.
    """
    data = _load_json_like(path)
    try:
        info = data.get("info", {})
        duration = float(info.get("duration", info.get("Duration")))
        if "events" in data:
            events = [(e["event"], float(e["startTime"]), float(e["endTime"])) for e in data["events"]]
        else:
            events = [(e["event"], float(e["hdTimeStart"]), float(e["hdTimeEnd"])) for e in data["markResult"]["marks"]]
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise CaptureError(path, f"expected info.duration and events (or markResult.marks) with times ({exc})") from None
    if not duration > 0:
        raise CaptureError(path, f"info.duration must be positive, got {duration}")
    rate = frame_count / duration
    spans = []
    for name, start, end in events:
        if any(word in str(name).lower() for word in INTERACTION_WORDS):
            first, last = int(np.floor(start * rate)), int(np.ceil(end * rate)) - 1
            if last >= first:
                spans.append((max(0, first), min(frame_count - 1, last)))
    return spans, duration


def choose_base(boxes: dict[str, PartBoxes], T_world_camera: dict[int, FloatArray]) -> str:
    """Label of the object's fixed body (see BASE_LABELS)."""
    for label in BASE_LABELS:
        if label in boxes:
            return label
    if T_world_camera:
        def spread(b: PartBoxes) -> float:
            frames = [f for f in b.T_camera_part if f in T_world_camera]
            if len(frames) < 2:
                return np.inf
            centres = np.array([(T_world_camera[f] @ b.T_camera_part[f])[:3, 3] for f in frames])
            return float(np.linalg.norm(centres.std(axis=0)))

        return min(boxes.values(), key=spread).label
    return next(iter(boxes))


def fit_part(
    name: str, body: PartBoxes, part: PartBoxes, T_world_camera: dict[int, FloatArray], frame_of: dict[int, int],
    spans: list[tuple[int, int]],
) -> tuple[GroundTruthPart, FloatArray] | None:
    """The joint of ``part`` relative to ``body`` in the world frame, or None if it does not move.

    Args:
        name: part name in gt.json.
        body, part: annotated boxes.
        T_world_camera: source frame -> (4, 4) camera-to-world pose.
        frame_of: source frame -> written frame index.
        spans: interaction spans in source frames.

    Returns:
        The ground-truth part (written-frame indices, canonical state at its first frame) and (N, 3) samples
        of its box surface at the canonical state, world frame.
    """
    frames = sorted(f for f in part.T_camera_part if f in body.T_camera_part and f in frame_of and f in T_world_camera)
    if len(frames) < 2:
        return None
    T_body_part = np.stack([invert_transform(body.T_camera_part[f]) @ part.T_camera_part[f] for f in frames])
    # Express the motion in the world through the body's pose at the first frame (the body is static).
    T_world_body = T_world_camera[frames[0]] @ body.T_camera_part[frames[0]]
    T_world_part = T_world_body @ T_body_part
    T_motion = T_world_part @ invert_transform(T_world_part[0])
    weights = np.ones(len(frames))
    centre = T_world_part[0, :3, 3]
    angles = np.linalg.norm(Rotation.from_matrix(T_motion[:, :3, :3]).as_rotvec(), axis=1)
    pivot = None
    if angles.max() > MIN_REVOLUTE_RAD:
        joint_type = "revolute"
        axis, pivot, states = fit_revolute_motions(T_motion, weights, centre)
    else:
        joint_type = "prismatic"
        axis, states = fit_prismatic_motions(T_motion, weights, centre)
        if np.abs(states).max() < MIN_PRISMATIC_M:
            return None
    if states[np.argmax(np.abs(states))] < 0:  # opening is the positive direction
        axis, states = -axis, -states
    written = [frame_of[f] for f in frames]
    moved = [(frame_of.get(a), frame_of.get(b)) for a, b in spans if _changes(frames, states, a, b)]
    intervals = tuple((a, b) for a, b in moved if a is not None and b is not None)
    box = trimesh.creation.box(extents=part.extents_m, transform=T_world_part[0])
    points = np.asarray(box.sample(POINTS_PER_PART, seed=0), dtype=np.float64)
    gt_part = GroundTruthPart(make_part(name, joint_type, axis, pivot, written, states), centre, intervals)
    return gt_part, points


def _changes(frames: list[int], states: FloatArray, first: int, last: int) -> bool:
    """True if the part's state changes inside the source-frame span (the event acts on this part)."""
    inside = [s for f, s in zip(frames, states) if first <= f <= last]
    if len(inside) < 2:
        return False
    return float(np.ptp(inside)) > 0.25 * float(np.ptp(states))


def camera_from_body(body: PartBoxes) -> dict[int, FloatArray]:
    """Camera-to-world poses from the body's box when HOI4D's camera log is absent: the body is static, so
    T_world_camera(i) = T_camera_body(0) @ inv(T_camera_body(i)), with the world at the first annotated camera."""
    frames = sorted(body.T_camera_part)
    T_world_body = body.T_camera_part[frames[0]]
    return {f: T_world_body @ invert_transform(body.T_camera_part[f]) for f in frames}


__all__ = [
    "BASE_LABELS",
    "INTERACTION_WORDS",
    "PartBoxes",
    "camera_from_body",
    "choose_base",
    "fit_part",
    "read_interactions",
    "read_objpose",
    "read_trajectory",
]
