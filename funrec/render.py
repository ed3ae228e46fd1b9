"""Pictures of a twin for people without a 3D viewer: its MuJoCo export rendered offscreen at
several joint states, as PNG images and an animated GIF."""

from __future__ import annotations

import logging
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from funrec.errors import FunrecError
from funrec.formats.camera_poses import read_camera_poses
from funrec.formats.staged_folder import discard_folder, publish_files
from funrec.formats.twin import ArticulatedPart, read_articulation
from funrec.offscreen import ensure_gl_backend

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RenderConfig:
    """Settings of :func:`render_twin`."""

    width: int = 640
    """Image width, pixels."""
    height: int = 480
    """Image height, pixels."""
    states: int = 5
    """Joint states per part, evenly spread over its observed range."""
    zoom_out: float = 1.6
    """The view is the person's at the middle of the first interaction, moved back along the
    line of sight by this factor so the part's surroundings are in the picture."""
    part_rgba: tuple[float, float, float, float] = (1.0, 0.55, 0.1, 1.0)
    """Colour of the articulated parts (the static scene keeps its export colour)."""
    gif_frame_s: float = 0.4
    """Time each image is shown in the GIF, seconds."""
    label: bool = True
    """Write the part name and joint state on each image (a band along the top)."""


def _view(T_world_camera: np.ndarray, target: np.ndarray) -> tuple[float, float, float]:
    """Distance (m), azimuth and elevation (degrees) of a MuJoCo free camera looking at
    ``target`` from where the camera of one frame stood (the twin frame is z up)."""
    forward = target - T_world_camera[:3, 3]
    distance = float(np.linalg.norm(forward))
    forward = forward / max(distance, 1e-9)
    azimuth = np.degrees(np.arctan2(forward[1], forward[0]))
    elevation = np.degrees(np.arcsin(np.clip(forward[2], -1.0, 1.0)))
    return distance, float(azimuth), float(elevation)


def render_twin(twin_dir: str | Path, out_dir: str | Path, config: RenderConfig = RenderConfig()) -> list[Path]:  # noqa: B008
    """Render ``twin.xml`` of a twin folder at several joint states of each part.

    One PNG per (part, state) named ``<part>_state<k>.png``, an ``overview.png`` at the canonical
    state, and ``twin.gif`` cycling through all of them.

    Args:
        twin_dir: twin folder with twin.xml, articulation.json and camera_poses.txt.
        out_dir: folder for the images (created).
        config: settings.

    Returns:
        Paths written, the GIF last.

    Raises:
        FunrecError: twin.xml is missing or does not load, or offscreen rendering is unavailable.
    """
    twin_dir, out_dir = Path(twin_dir), Path(out_dir)
    xml = twin_dir / "twin.xml"
    if not xml.is_file():
        raise FunrecError(f"{xml}: missing (run funrec export {twin_dir} first)")
    articulation = read_articulation(twin_dir)
    T_world_camera = read_camera_poses(twin_dir / "camera_poses.txt").T_world_camera
    ensure_gl_backend()
    import mujoco

    try:
        model = mujoco.MjModel.from_xml_path(str(xml))
    except ValueError as exc:
        raise FunrecError(f"{xml}: MuJoCo cannot load it ({exc})") from None
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, config.width)
    model.vis.global_.offheight = max(model.vis.global_.offheight, config.height)
    # written into a staged folder and moved into out_dir when all are done: Ctrl-C leaves no partial set
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staged = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.partial-", dir=out_dir.parent))
    try:
        names = [p.name for p in _render_all(model, articulation, T_world_camera, staged, config)]
    except BaseException:
        discard_folder(staged)
        raise
    publish_files(staged, out_dir)
    log.info("rendered %d images of %s", len(names) - 1, twin_dir)
    return [out_dir / name for name in names]


def _render_all(model, articulation, T_world_camera: np.ndarray, out_dir: Path, config: RenderConfig) -> list[Path]:  # noqa: ANN001
    """The pictures and the GIF of :func:`render_twin`, written into ``out_dir``."""
    import mujoco
    from PIL import Image

    data = mujoco.MjData(model)
    written: list[Path] = []
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    with mujoco.Renderer(model, config.height, config.width) as renderer:

        def shoot(path: Path, label: str) -> None:
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera)
            image = Image.fromarray(renderer.render())
            if config.label:
                _draw_label(image, label)
            image.save(path)
            written.append(path)

        for part in articulation.parts:
            body = model.jnt_bodyid[model.joint(part.name).id]
            model.geom_rgba[model.geom_bodyid == body] = config.part_rgba
        mujoco.mj_forward(model, data)

        def aim(part: ArticulatedPart | None) -> None:
            """Look at the part (or ahead of camera 0) from where the person stood mid-way through it."""
            if part is None:
                target, frame = T_world_camera[0, :3, 3] + T_world_camera[0, :3, 2] * 1.5, 0
            else:
                target = data.xipos[model.jnt_bodyid[model.joint(part.name).id]].copy()
                frame = int(part.frames[len(part.frames) // 2])
            distance, camera.azimuth, camera.elevation = _view(T_world_camera[frame], target)
            camera.lookat[:] = target
            camera.distance = distance * config.zoom_out

        aim(articulation.parts[0] if articulation.parts else None)
        shoot(out_dir / "overview.png", "overview: every part at its canonical state (0)")
        for part in articulation.parts:
            aim(part)  # each part from its own viewpoint: parts of one room may be metres apart
            joint = model.joint(part.name)
            lower, upper = model.jnt_range[joint.id]
            for k, state in enumerate(np.linspace(lower, upper, config.states)):
                data.qpos[:] = 0.0
                data.qpos[model.jnt_qposadr[joint.id]] = state
                shoot(out_dir / f"{part.name}_state{k}.png", _state_label(part, float(state)))
            data.qpos[:] = 0.0
    images = [Image.open(path) for path in written]
    gif = out_dir / "twin.gif"
    images[0].save(gif, save_all=True, append_images=images[1:], duration=int(config.gif_frame_s * 1000), loop=0)
    written.append(gif)
    return written


def _state_label(part: ArticulatedPart, state: float) -> str:
    """E.g. ``part_0 (revolute) state 0.785 rad (45.0 deg)`` or ``part_1 (prismatic) state 0.120 m``."""
    if part.joint_type == "revolute":
        return f"{part.name} ({part.joint_type}) state {state:.3f} rad ({np.degrees(state):.1f} deg)"
    return f"{part.name} ({part.joint_type}) state {state:.3f} m"


def _draw_label(image: Any, text: str) -> None:
    """Write ``text`` in white on a dark band along the top of a PIL image."""
    from PIL import ImageDraw, ImageFont

    font = ImageFont.load_default(size=max(10, image.height // 28))
    draw = ImageDraw.Draw(image)
    band = int(font.size * 1.6)
    draw.rectangle([0, 0, image.width, band], fill=(20, 20, 20))
    draw.text((int(font.size * 0.5), int(font.size * 0.3)), text, fill=(255, 255, 255), font=font)


__all__ = ["RenderConfig", "render_twin"]
