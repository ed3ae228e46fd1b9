"""Interactive browser view of a twin folder with viser: the static mesh, each part moved by a
slider over its observed range, the camera path, and the contact points and grasp frames.

viser is an optional dependency (``pip install funrec[view]``); it is imported only here.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from funrec.errors import FunrecError
from funrec.formats.affordances import AFFORDANCES_FILE, Affordances, read_affordances
from funrec.formats.camera_poses import read_camera_poses
from funrec.formats.meshes import load_ply
from funrec.formats.twin import ArticulatedPart, read_articulation
from funrec.geometry.joints import joint_transform

logger = logging.getLogger(__name__)

INSTALL_HINT = "pip install funrec[view]"
"""What to run when viser is missing."""


@dataclass(frozen=True)
class ViewConfig:
    """Settings of :func:`build_twin_view`; lengths in metres."""

    frustum_every: int = 10
    """A camera frustum is drawn at every k-th pose of camera_poses.txt (the path is drawn whole)."""
    frustum_fov_deg: float = 60.0
    """Vertical field of view of the drawn frustums, degrees: the twin folder stores no intrinsics,
    so the frustums show where the camera was and where it looked, not its exact field of view."""
    frustum_aspect: float = 4.0 / 3.0
    """Width / height of the drawn frustums (see ``frustum_fov_deg``)."""
    frustum_scale: float = 0.08
    """Size of the drawn frustums, metres."""
    path_thickness: float = 0.006
    """Thickness of the camera path polyline, metres."""
    contact_radius: float = 0.015
    """Radius of the sphere drawn at each contact point, metres."""
    grasp_axes_length: float = 0.08
    """Length of the drawn grasp frame axes, metres."""
    slider_steps: int = 100
    """Steps of each joint slider over the part's range."""

    def __post_init__(self) -> None:
        if self.frustum_every < 1 or self.slider_steps < 1 or not 0.0 < self.frustum_fov_deg < 180.0:
            raise ValueError(f"ViewConfig needs frustum_every >= 1, slider_steps >= 1 and 0 < frustum_fov_deg < 180, got {self}")


@dataclass
class TwinView:
    """The scene built for one twin on a viser server: handles by role, for updates and tests."""

    twin_dir: Path
    """The twin folder shown."""
    parts: dict[str, ArticulatedPart]
    """Articulated parts by name, as read from articulation.json."""
    part_nodes: dict[str, Any] = field(default_factory=dict)
    """Part name -> scene node (a frame) whose pose is the part's joint transform; the part's mesh,
    contact point and grasp frame are its children (world coordinates at the canonical state)."""
    sliders: dict[str, Any] = field(default_factory=dict)
    """Part name -> GUI slider of its joint state (rad or m)."""
    nodes: dict[str, Any] = field(default_factory=dict)
    """Every other scene node by scene name (static mesh, camera path, frustums, contacts, grasps)."""

    def set_state(self, name: str, state: float) -> None:
        """Move part ``name`` to joint ``state`` (what its slider does): the node's pose becomes
        ``joint_transform(state)`` (FORMATS.md section 2)."""
        import viser.transforms as vtf

        part = self.parts[name]
        T_world_part = joint_transform(part.joint_type, part.axis_world, part.pivot_world, float(state))
        node = self.part_nodes[name]
        node.wxyz = vtf.SO3.from_matrix(T_world_part[:3, :3]).wxyz
        node.position = T_world_part[:3, 3]


def import_viser() -> Any:
    """The viser module, or a FunrecError that says how to install it."""
    try:
        import viser
    except ImportError:
        raise FunrecError(f"funrec view needs the viser package, which is not installed: {INSTALL_HINT}") from None
    return viser


def _add_geometry(scene: Any, name: str, path: Path, colour: tuple[int, int, int]) -> Any:
    geometry = load_ply(path)
    if isinstance(geometry, trimesh.Trimesh):
        return scene.add_mesh_trimesh(name, geometry)
    return scene.add_point_cloud(name, geometry.astype(np.float32), colors=colour, point_size=0.005)


def _add_camera_path(view: TwinView, scene: Any, config: ViewConfig) -> None:
    import viser.transforms as vtf

    poses = read_camera_poses(view.twin_dir / "camera_poses.txt")
    positions = poses.T_world_camera[:, :3, 3]
    if len(positions) >= 2:
        segments = np.stack([positions[:-1], positions[1:]], axis=1).astype(np.float32)
        view.nodes["/camera_path"] = scene.add_line_segments("/camera_path", segments, colors=(40, 90, 200), thickness=config.path_thickness)
    # camera_poses.txt is T_world_camera in the OpenCV convention, which viser's frustums share.
    for frame, T_world_camera in list(zip(poses.frames, poses.T_world_camera))[:: config.frustum_every]:
        name = f"/cameras/{int(frame):06d}"
        view.nodes[name] = scene.add_camera_frustum(
            name, fov=np.radians(config.frustum_fov_deg), aspect=config.frustum_aspect, scale=config.frustum_scale,
            color=(40, 90, 200), wxyz=vtf.SO3.from_matrix(T_world_camera[:3, :3]).wxyz, position=T_world_camera[:3, 3],
        )


def _add_affordances(view: TwinView, scene: Any, affordances: Affordances, config: ViewConfig) -> None:
    import viser.transforms as vtf

    for affordance in affordances.parts:
        if affordance.name not in view.part_nodes:
            logger.warning("%s: affordance of %s, which articulation.json does not have", view.twin_dir / AFFORDANCES_FILE, affordance.name)
            continue
        # Children of the part node, given at the canonical state: they move with the slider.
        base = f"/parts/{affordance.name}"
        view.nodes[f"{base}/contact"] = scene.add_icosphere(
            f"{base}/contact", radius=config.contact_radius, color=(230, 40, 40), position=affordance.contact_point
        )
        T = affordance.T_world_grasp
        view.nodes[f"{base}/grasp"] = scene.add_frame(
            f"{base}/grasp", axes_length=config.grasp_axes_length, axes_radius=config.grasp_axes_length / 20,
            wxyz=vtf.SO3.from_matrix(T[:3, :3]).wxyz, position=T[:3, 3],
        )


def build_twin_view(server: Any, twin_dir: str | Path, config: ViewConfig = ViewConfig()) -> TwinView:  # noqa: B008 (frozen)
    """Put a twin into a viser server's scene and add a slider per joint.

    Args:
        server: a ``viser.ViserServer``.
        twin_dir: the twin folder (articulation.json, camera_poses.txt, meshes/, and
            affordances.json when present).
        config: drawing settings.

    Returns:
        The :class:`TwinView` with every handle.

    Raises:
        FormatError: a twin file is missing or malformed (names the file).
    """
    twin_dir = Path(twin_dir)
    articulation = read_articulation(twin_dir / "articulation.json")
    view = TwinView(twin_dir, {p.name: p for p in articulation.parts})
    scene = server.scene
    if articulation.static_mesh is not None:
        view.nodes["/static"] = _add_geometry(scene, "/static", twin_dir / articulation.static_mesh, (160, 160, 160))
    for part in articulation.parts:
        base = f"/parts/{part.name}"
        view.part_nodes[part.name] = scene.add_frame(base, show_axes=False)
        if part.mesh is not None:
            view.nodes[f"{base}/mesh"] = _add_geometry(scene, f"{base}/mesh", twin_dir / part.mesh, (220, 150, 60))
        lower, upper = part.state_range
        slider = server.gui.add_slider(
            f"{part.name} ({part.joint_type}, {'rad' if part.joint_type == 'revolute' else 'm'})",
            min=float(lower), max=float(max(upper, lower + 1e-6)), step=float(max(upper - lower, 1e-6)) / config.slider_steps,
            initial_value=float(np.clip(0.0, lower, upper)),
        )
        slider.on_update(lambda _event, name=part.name, slider=slider: view.set_state(name, slider.value))
        view.sliders[part.name] = slider
        view.set_state(part.name, slider.value)
    _add_camera_path(view, scene, config)
    if (twin_dir / AFFORDANCES_FILE).is_file():
        _add_affordances(view, scene, read_affordances(twin_dir / AFFORDANCES_FILE), config)
    return view


def serve_twin(
    twin_dir: str | Path,
    host: str = "127.0.0.1",
    port: int = 8080,
    config: ViewConfig = ViewConfig(),  # noqa: B008 (frozen, immutable default)
    on_ready: Callable[[str], None] | None = None,
) -> None:
    """Serve the twin at ``http://host:port`` until interrupted (Ctrl+C); ``on_ready(url)`` is
    called once the scene is built.

    Raises:
        FunrecError: viser is not installed (the message says how to install it).
        FormatError: a twin file is missing or malformed.
    """
    viser = import_viser()
    twin_dir = Path(twin_dir)
    read_articulation(twin_dir / "articulation.json")  # fail on a bad twin before starting a server
    server = viser.ViserServer(host=host, port=port, verbose=False)
    try:
        build_twin_view(server, twin_dir, config)
        if on_ready is not None:
            on_ready(f"http://{host}:{port}")
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()


__all__ = ["INSTALL_HINT", "TwinView", "ViewConfig", "build_twin_view", "import_viser", "serve_twin"]
