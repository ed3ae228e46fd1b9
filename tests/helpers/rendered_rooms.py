"""A small ray-cast renderer of textured rectangles, and the room scenes it draws: enough geometry
for known-answer tests of camera tracking and point tracks (a room, a cabinet whose door swings
open about a known hinge revealing its interior, and a hand moving on its own).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from funrec.formats.capture import CaptureIntrinsics, CaptureWriter
from funrec.geometry.transforms import invert_transform, make_transform, rotation_about_axis

LABEL_STATIC, LABEL_DOOR, LABEL_INTERIOR, LABEL_HAND = 1, 2, 3, 4


@dataclass(frozen=True)
class Rect:
    """A textured rectangle: local x in [0, width], y in [0, height], normal = local z."""

    T_world_rect: Callable[[int], np.ndarray]
    """frame -> (4, 4) pose of the rectangle's corner frame in the world."""
    width: float
    height: float
    texture: np.ndarray
    label: int
    ellipse: bool = False


def noise_texture(rng: np.random.Generator, width_m: float, height_m: float) -> np.ndarray:
    """Multi-octave colour noise with a fixed physical scale (blobs of 2-60 cm on a 4 mm
    texel grid), so that big walls are as textured as small doors and nothing is finer
    than the pixels can resolve (no aliasing flicker).

    Returns:
        (rows, cols, 3) uint8 texture spanning width_m x height_m.
    """
    texel_m = 0.004
    cols, rows = int(width_m / texel_m), int(height_m / texel_m)
    texture = np.zeros((rows, cols, 3), np.float32)
    for blob_m, amplitude in ((0.6, 0.6), (0.25, 0.8), (0.1, 1.0), (0.05, 0.8), (0.025, 0.5)):
        coarse = rng.random((max(2, int(height_m / blob_m)), max(2, int(width_m / blob_m)), 3)).astype(np.float32)
        texture += amplitude * cv2.resize(coarse, (cols, rows), interpolation=cv2.INTER_CUBIC)
    texture -= texture.min()
    return (255 * texture / texture.max()).astype(np.uint8)


def fixed(T: np.ndarray) -> Callable[[int], np.ndarray]:
    return lambda frame: T


def frame_axes(origin, e1, e2) -> np.ndarray:
    e1, e2 = np.asarray(e1, float), np.asarray(e2, float)
    return make_transform(np.stack([e1, e2, np.cross(e1, e2)], axis=1), origin)


def render(rects: list[Rect], T_world_camera: np.ndarray, K: np.ndarray, W: int, H: int, frame: int):
    """Render (rgb (H,W,3) uint8, depth_m (H,W), label (H,W) int) by ray casting."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    depth = np.full((H, W), np.inf)
    rgb = np.zeros((H, W, 3), np.uint8)
    label = np.zeros((H, W), np.int64)
    for rect in rects:
        T_camera_rect = invert_transform(T_world_camera) @ rect.T_world_rect(frame)
        o, e1, e2, n = T_camera_rect[:3, 3], T_camera_rect[:3, 0], T_camera_rect[:3, 1], T_camera_rect[:3, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (o @ n) / (d @ n)
        hit = t[..., None] * d - o
        a, b = hit @ e1, hit @ e2
        inside = (t > 0.05) & (a >= 0) & (a <= rect.width) & (b >= 0) & (b <= rect.height)
        if rect.ellipse:
            inside &= ((a / rect.width - 0.5) ** 2 + (b / rect.height - 0.5) ** 2) <= 0.25
        closer = inside & (t < depth)
        th, tw = rect.texture.shape[:2]
        map_x = (a / rect.width * (tw - 1)).astype(np.float32)
        map_y = (b / rect.height * (th - 1)).astype(np.float32)
        colour = cv2.remap(rect.texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        depth[closer], rgb[closer], label[closer] = t[closer], colour[closer], rect.label
    depth[~np.isfinite(depth)] = 0.0
    return rgb, depth, label


@dataclass(frozen=True)
class Scene:
    rects: list[Rect]
    T_world_camera: np.ndarray
    """(F, 4, 4) true camera poses."""
    T_world_door: np.ndarray
    """(F, 4, 4) door motion: canonical (frame 0) door points to where they are at frame f."""
    K: np.ndarray
    width: int
    height: int


DOOR_HINGE_WORLD = np.array([0.2, 0.0, 2.0])
DOOR_AXIS_WORLD = np.array([0.0, -1.0, 0.0])


def make_scene(frames: int, width: int = 320, height: int = 240, hand: bool = False, door_max_rad: float = 1.2,
               seed: int = 0) -> Scene:
    """A room (camera 0 looks at the back wall 2.5 m away), a cabinet whose door opens about a
    vertical hinge, and optionally an elliptical hand covering ~25 % of the image."""
    rng = np.random.default_rng(seed)
    f = 0.82 * width
    K = np.array([[f, 0, width / 2 - 0.5], [0, f, height / 2 - 0.5], [0, 0, 1.0]])
    s = np.linspace(0.0, 1.0, frames)
    position = np.stack([0.25 * np.sin(2 * np.pi * s), 0.06 * np.sin(4 * np.pi * s), 0.3 * s], axis=1)
    rotvec = np.stack([0.05 * np.sin(2 * np.pi * s), -0.15 * np.sin(2 * np.pi * s), 0.03 * np.sin(6 * np.pi * s)], axis=1)
    T_world_camera = make_transform(Rotation.from_rotvec(rotvec).as_matrix(), position)
    angle = door_max_rad * np.clip((s - 0.15) / 0.7, 0.0, 1.0)
    R_door = rotation_about_axis(DOOR_AXIS_WORLD, angle)
    T_world_door = make_transform(R_door, DOOR_HINGE_WORLD - R_door @ DOOR_HINGE_WORLD)
    rects = [
        Rect(fixed(frame_axes([-2.5, -1.6, 2.5], [1, 0, 0], [0, 1, 0])), 5.0, 3.2, noise_texture(rng, 5.0, 3.2), LABEL_STATIC),
        Rect(fixed(frame_axes([-2.5, 1.2, -0.5], [1, 0, 0], [0, 0, 1])), 5.0, 3.0, noise_texture(rng, 5.0, 3.0), LABEL_STATIC),
        Rect(fixed(frame_axes([-2.0, -1.6, -0.5], [0, 0, 1], [0, 1, 0])), 3.0, 2.8, noise_texture(rng, 3.0, 2.8), LABEL_STATIC),
        Rect(fixed(frame_axes([2.0, -1.6, -0.5], [0, 0, 1], [0, 1, 0])), 3.0, 2.8, noise_texture(rng, 3.0, 2.8), LABEL_STATIC),
        Rect(fixed(frame_axes([0.2, -0.5, 2.3], [1, 0, 0], [0, 1, 0])), 0.6, 0.8, noise_texture(rng, 0.6, 0.8), LABEL_INTERIOR),
    ]
    door_canonical = frame_axes([0.2, -0.5, 2.0], [1, 0, 0], [0, 1, 0])
    rects.append(Rect(lambda i: T_world_door[i] @ door_canonical, 0.6, 0.8, noise_texture(rng, 0.6, 0.8), LABEL_DOOR))
    if hand:
        # The hand moves independently of both camera and scene, ~0.7 m in front of the camera.
        def T_world_hand(i: int) -> np.ndarray:
            wobble = make_transform(Rotation.from_rotvec([0.3 * np.sin(0.3 * i), 0.2 * np.cos(0.2 * i), 0.4 * s[i]]).as_matrix(),
                                    [0.15 * np.sin(0.25 * i) - 0.05, 0.1 * np.cos(0.17 * i) - 0.05, 0.75])
            return T_world_camera[0] @ wobble @ frame_axes([-0.25, -0.17, 0.0], [1, 0, 0], [0, 1, 0])

        rects.append(Rect(T_world_hand, 0.5, 0.34, noise_texture(rng, 0.5, 0.34), LABEL_HAND, ellipse=True))
    return Scene(rects, T_world_camera, T_world_door, K, width, height)


def write_scene(scene: Scene, root: Path, hand_masks: bool = False, object_masks: bool = False,
                depth_noise_m: float = 0.001, seed: int = 1) -> Path:
    """Render every frame into a capture folder (depth noise sigma = depth_noise_m * z^2)."""
    rng = np.random.default_rng(seed)
    intrinsics = CaptureIntrinsics(scene.width, scene.height, scene.K[0, 0], scene.K[1, 1], scene.K[0, 2],
                                   scene.K[1, 2], depth_scale=1000.0, fps=15.0)
    writer = CaptureWriter(root, intrinsics)
    for i in range(len(scene.T_world_camera)):
        rgb, depth, label = render(scene.rects, scene.T_world_camera[i], scene.K, scene.width, scene.height, i)
        depth = np.where(depth > 0, depth + rng.normal(0.0, 1.0, depth.shape) * depth_noise_m * depth**2, 0.0)
        writer.write_frame(i, rgb, depth, hand_mask=(label == LABEL_HAND) if hand_masks else None,
                           object_mask=(label == LABEL_DOOR) if object_masks else None)
    return root
