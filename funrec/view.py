"""Interactive browser view of a twin folder with viser: the static mesh, the parts highlighted and
each moved by a slider over its observed range, a time slider that replays the capture (part
states, camera, contact and hand), and layers to toggle (camera path, frustums, contacts, hands).

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
from funrec.formats.capture import Capture, load_capture, read_mask
from funrec.formats.meshes import load_ply
from funrec.formats.twin import ArticulatedPart, read_articulation
from funrec.formats.twin_config import recorded_capture
from funrec.geometry.camera import backproject
from funrec.geometry.joints import joint_transform
from funrec.geometry.transforms import transform_points
from funrec.surfaces.hands import TWIN_HAND_MASKS
from funrec.typed import FloatArray

logger = logging.getLogger(__name__)

INSTALL_HINT = "pip install funrec[view]"
"""What to run when viser is missing."""
LAYERS = ("camera path", "frustums", "contacts", "hands")
"""Layers the viewer can toggle, each a checkbox."""
CAMERA_COLOUR = (40, 90, 200)
CURRENT_CAMERA_COLOUR = (20, 20, 20)
HAND_COLOUR = (230, 60, 160)


@dataclass(frozen=True)
class ViewConfig:
    """Settings of :func:`build_twin_view`; lengths in metres."""

    frustum_every: int = 10
    """A camera frustum is drawn at every k-th pose of camera_poses.txt (the path is drawn whole)."""
    frustum_fov_deg: float = 60.0
    """Vertical field of view of the drawn frustums, degrees, when the capture is not at hand (its
    intrinsics give the true one)."""
    frustum_aspect: float = 4.0 / 3.0
    """Width / height of the drawn frustums when the capture is not at hand."""
    frustum_scale: float = 0.08
    """Depth of the drawn frustums, metres."""
    line_thickness: float = 2.0
    """Thickness of the camera path and frustum lines, screen pixels."""
    contact_radius: float = 0.015
    """Radius of the sphere drawn at each contact point, metres."""
    grasp_axes_length: float = 0.08
    """Length of the drawn grasp frame axes, metres."""
    slider_steps: int = 100
    """Steps of each joint slider over the part's range."""
    part_colour: tuple[int, int, int] = (255, 140, 0)
    """Colour the parts are drawn in, so they stand out from the scan of the room."""
    hand_points: int = 3000
    """Most hand points drawn at the current frame (back-projected hand mask pixels)."""
    static_max_triangles: int = 150_000
    """A static mesh with more triangles is decimated (quadric, Open3D) to this many for the
    browser: a room scan has ~500k, which software WebGL (and a weak GPU) draws at a few seconds
    per frame. 0 keeps every triangle."""

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
    T_world_camera: FloatArray
    """(F, 4, 4) camera poses of every frame (camera_poses.txt)."""
    capture: Capture | None = None
    """The capture the twin was made from, when found (hand points, true frustum shape)."""
    part_nodes: dict[str, Any] = field(default_factory=dict)
    """Part name -> scene node (a frame) whose pose is the part's joint transform; the part's mesh,
    contact point and grasp frame are its children (world coordinates at the canonical state)."""
    sliders: dict[str, Any] = field(default_factory=dict)
    """Part name -> GUI slider of its joint state (rad or m)."""
    time_slider: Any = None
    """GUI slider of the frame shown; moving it replays the capture."""
    layers: dict[str, list[Any]] = field(default_factory=dict)
    """Layer name (LAYERS) -> its scene nodes."""
    checkboxes: dict[str, Any] = field(default_factory=dict)
    """Layer name -> GUI checkbox that shows or hides it."""
    nodes: dict[str, Any] = field(default_factory=dict)
    """Every other scene node by scene name (static mesh, camera path, frustums, contacts, grasps)."""
    server: Any = None
    """The viser server."""
    hand_points_max: int = 3000
    """Most hand points drawn (ViewConfig.hand_points)."""

    def set_state(self, name: str, state: float) -> None:
        """Move part ``name`` to joint ``state`` (what its slider does): the node's pose becomes
        ``joint_transform(state)`` (FORMATS.md section 2)."""
        import viser.transforms as vtf

        part = self.parts[name]
        T_world_part = joint_transform(part.joint_type, part.axis_world, part.pivot_world, float(state))
        node = self.part_nodes[name]
        node.wxyz = vtf.SO3.from_matrix(T_world_part[:3, :3]).wxyz
        node.position = T_world_part[:3, 3]

    def state_at(self, name: str, frame: int) -> float:
        """The part's joint state at a frame: interpolated between tracked frames, held before the
        first and after the last (as :func:`funrec.surfaces.hands.part_poses`)."""
        part = self.parts[name]
        if len(part.frames) == 0:
            return 0.0
        return float(np.interp(frame, part.frames, part.states))

    def set_frame(self, frame: int) -> None:
        """Show the capture at ``frame`` (what the time slider does): every part at its state
        then (its joint slider follows), the current camera at its pose, the hand points then."""
        import viser.transforms as vtf

        for name, slider in self.sliders.items():
            state = float(np.clip(self.state_at(name, frame), slider.min, slider.max))
            slider.value = state
            self.set_state(name, state)
        T = self.T_world_camera[frame]
        camera = self.nodes["/current_camera"]
        camera.wxyz = vtf.SO3.from_matrix(T[:3, :3]).wxyz
        camera.position = T[:3, 3]
        if "/hands/points" in self.nodes:
            # An empty point cloud stalls the browser's renderer: keep one point, hidden.
            points = _hand_points(self, frame)
            node = self.nodes["/hands/points"]
            node.points = points if len(points) else np.zeros((1, 3), np.float32)
            box = self.checkboxes.get("hands")
            node.visible = bool(len(points)) and (box is None or bool(box.value))

    def set_layer(self, layer: str, visible: bool) -> None:
        """Show or hide a layer (what its checkbox does)."""
        for node in self.layers.get(layer, []):
            node.visible = visible
        if layer == "hands" and visible and self.time_slider is not None:
            self.set_frame(int(self.time_slider.value))  # hides the hand again at a frame without one


def import_viser() -> Any:
    """The viser module, or a FunrecError that says how to install it."""
    try:
        import viser
    except ImportError:
        raise FunrecError(f"funrec view needs the viser package, which is not installed: {INSTALL_HINT}") from None
    return viser


def _decimated(mesh: trimesh.Trimesh, max_triangles: int) -> trimesh.Trimesh:
    """The mesh with at most ``max_triangles`` triangles (quadric decimation keeps vertex colours)."""
    if max_triangles <= 0 or len(mesh.faces) <= max_triangles:
        return mesh
    import open3d as o3d

    o3d_mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices, dtype=np.float64)),
                                         o3d.utility.Vector3iVector(np.asarray(mesh.faces, dtype=np.int32)))
    if mesh.visual.kind == "vertex":
        o3d_mesh.vertex_colors = o3d.utility.Vector3dVector(np.asarray(mesh.visual.vertex_colors)[:, :3] / 255.0)
    small = o3d_mesh.simplify_quadric_decimation(max_triangles)
    colours = (np.asarray(small.vertex_colors) * 255.0).astype(np.uint8) if small.has_vertex_colors() else None
    return trimesh.Trimesh(np.asarray(small.vertices), np.asarray(small.triangles), vertex_colors=colours, process=False)


def _add_geometry(scene: Any, name: str, path: Path, colour: tuple[int, int, int] | None, max_triangles: int = 0) -> Any:
    """A mesh (its vertex colours, or ``colour`` when given; decimated to ``max_triangles``) or a point cloud."""
    geometry = load_ply(path)
    if isinstance(geometry, trimesh.Trimesh):
        geometry = _decimated(geometry, max_triangles)
        if colour is None:
            return scene.add_mesh_trimesh(name, geometry)
        return scene.add_mesh_simple(name, np.asarray(geometry.vertices, dtype=np.float32),
                                     np.asarray(geometry.faces, dtype=np.uint32), color=colour, side="double")
    return scene.add_point_cloud(name, geometry.astype(np.float32), colors=colour or (160, 160, 160), point_size=0.005)


def frustum_segments(T_world_camera: FloatArray, K: FloatArray, width: int, height: int, depth: float) -> FloatArray:
    """Camera frustums as line segments: apex to the four image corners, and the image rectangle.

    Args:
        T_world_camera: (N, 4, 4) camera poses (OpenCV camera frame).
        K: (3, 3) intrinsics giving the frustum's shape.
        width: image width, pixels.
        height: image height, pixels.
        depth: distance of the drawn image rectangle from the apex along z, metres.

    Returns:
        (N * 8, 2, 3) segment end points, world frame.
    """
    corners_px = np.array([[0.0, 0.0], [width, 0.0], [width, height], [0.0, height]])
    corners_camera = np.column_stack([(corners_px - K[:2, 2]) / np.diag(K)[:2], np.ones(4)]) * depth
    segments_camera = np.concatenate([
        np.stack([np.zeros((4, 3)), corners_camera], axis=1),
        np.stack([corners_camera, np.roll(corners_camera, -1, axis=0)], axis=1),
    ])  # (8, 2, 3)
    p_world = np.einsum("nij,skj->nski", T_world_camera[:, :3, :3], segments_camera) + T_world_camera[:, None, None, :3, 3]
    return p_world.reshape(-1, 2, 3)


def _intrinsics(view: TwinView, config: ViewConfig) -> tuple[FloatArray, int, int]:
    """(K, width, height) of the capture, or of a nominal camera of ViewConfig's field of view."""
    if view.capture is not None:
        K = view.capture.intrinsics
        return K.K, K.width, K.height
    height = 480
    width = int(round(height * config.frustum_aspect))
    f = height / 2.0 / np.tan(np.radians(config.frustum_fov_deg) / 2.0)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]]), width, height


def _add_cameras(view: TwinView, scene: Any, config: ViewConfig) -> None:
    K, width, height = _intrinsics(view, config)
    positions = view.T_world_camera[:, :3, 3]
    if len(positions) >= 2:
        segments = np.stack([positions[:-1], positions[1:]], axis=1).astype(np.float32)
        view.nodes["/camera_path"] = scene.add_line_segments(
            "/camera_path", segments, colors=CAMERA_COLOUR, thickness=config.line_thickness, thickness_units="screen")
        view.layers["camera path"].append(view.nodes["/camera_path"])
    # Frustums as thin lines, never filled: they sit where the person stood, in front of the part.
    shown = view.T_world_camera[:: config.frustum_every]
    view.nodes["/cameras"] = scene.add_line_segments(
        "/cameras", frustum_segments(shown, K, width, height, config.frustum_scale).astype(np.float32),
        colors=CAMERA_COLOUR, thickness=config.line_thickness * 0.5, thickness_units="screen")
    view.layers["frustums"].append(view.nodes["/cameras"])
    current = frustum_segments(np.eye(4)[None], K, width, height, 2.0 * config.frustum_scale).astype(np.float32)
    view.nodes["/current_camera"] = scene.add_line_segments(
        "/current_camera", current, colors=CURRENT_CAMERA_COLOUR, thickness=config.line_thickness * 1.5,
        thickness_units="screen")
    view.layers["frustums"].append(view.nodes["/current_camera"])


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
        view.layers["contacts"] += [view.nodes[f"{base}/contact"], view.nodes[f"{base}/grasp"]]


def _hand_points(view: TwinView, frame: int) -> FloatArray:
    """(N, 3) float32 world points of the hand at a frame: its mask's pixels lifted by the depth
    (the capture's hand masks, else the twin's detected ones); (0, 3) without them."""
    capture = view.capture
    assert capture is not None
    hand = capture.mask("hand", frame)
    detected = view.twin_dir / TWIN_HAND_MASKS / f"{frame:06d}.png"
    if hand is None and detected.is_file():
        hand = read_mask(detected)
    if hand is None or not hand.any():
        return np.zeros((0, 3), dtype=np.float32)
    p_camera = backproject(capture.depth_m(frame), capture.intrinsics.K)[hand.ravel()]
    p_camera = p_camera[np.isfinite(p_camera).all(axis=1)]
    step = max(1, -(-len(p_camera) // view.hand_points_max))  # ceil: at most hand_points_max
    return transform_points(view.T_world_camera[frame], p_camera[::step]).astype(np.float32)


def _aim_camera(server: Any, view: TwinView, twin_dir: Path, articulation: Any) -> None:
    """Start the browser camera where the person stood, looking at the parts (or the scene)."""
    targets = [load_ply(twin_dir / p.mesh) for p in articulation.parts if p.mesh is not None]
    if not targets and articulation.static_mesh is not None:
        targets = [load_ply(twin_dir / articulation.static_mesh)]
    clouds = [np.asarray(t.vertices if isinstance(t, trimesh.Trimesh) else t) for t in targets] or [view.T_world_camera[:, :3, 3]]
    centres = np.array([(c.min(axis=0) + c.max(axis=0)) / 2.0 for c in clouds])  # each part counts once
    look_at = centres.mean(axis=0)
    radius = max(float(np.linalg.norm(np.concatenate(clouds) - look_at, axis=1).max()), 0.2)
    from_person = view.T_world_camera[:, :3, 3].mean(axis=0) - look_at
    from_person[2] = max(from_person[2], 0.3 * np.linalg.norm(from_person[:2]))  # from slightly above
    direction = from_person / max(np.linalg.norm(from_person), 1e-9)
    server.initial_camera.look_at = look_at
    server.initial_camera.position = look_at + direction * max(3.0 * radius, 1.0)
    server.initial_camera.up = (0.0, 0.0, 1.0)


def build_twin_view(
    server: Any, twin_dir: str | Path, config: ViewConfig = ViewConfig(), capture_dir: str | Path | None = None,  # noqa: B008 (frozen)
) -> TwinView:
    """Put a twin into a viser server's scene, with a slider per joint, a time slider and layer
    checkboxes, and aim the start camera at the parts.

    Args:
        server: a ``viser.ViserServer``.
        twin_dir: the twin folder (articulation.json, camera_poses.txt, meshes/, and
            affordances.json when present).
        config: drawing settings.
        capture_dir: the capture the twin was made from (hand points, true frustums); default
            the one the twin's config.json names, if it still exists.

    Returns:
        The :class:`TwinView` with every handle.

    Raises:
        FormatError: a twin file is missing or malformed (names the file).
    """
    twin_dir = Path(twin_dir)
    articulation = read_articulation(twin_dir / "articulation.json")
    T_world_camera = read_camera_poses(twin_dir / "camera_poses.txt").T_world_camera
    capture_dir = capture_dir if capture_dir is not None else recorded_capture(twin_dir)
    capture = load_capture(capture_dir) if capture_dir is not None else None
    view = TwinView(twin_dir, {p.name: p for p in articulation.parts}, T_world_camera, capture, server=server,
                    layers={layer: [] for layer in LAYERS}, hand_points_max=config.hand_points)
    scene = server.scene
    if articulation.static_mesh is not None:
        view.nodes["/static"] = _add_geometry(scene, "/static", twin_dir / articulation.static_mesh, None,
                                              config.static_max_triangles)
    for part in articulation.parts:
        base = f"/parts/{part.name}"
        view.part_nodes[part.name] = scene.add_frame(base, show_axes=False)
        if part.mesh is not None:
            view.nodes[f"{base}/mesh"] = _add_geometry(scene, f"{base}/mesh", twin_dir / part.mesh, config.part_colour)
    _add_cameras(view, scene, config)
    if (twin_dir / AFFORDANCES_FILE).is_file():
        _add_affordances(view, scene, read_affordances(twin_dir / AFFORDANCES_FILE), config)
    if capture is not None:
        view.nodes["/hands/points"] = scene.add_point_cloud("/hands/points", np.zeros((1, 3), np.float32),
                                                            colors=HAND_COLOUR, point_size=0.006, visible=False)
        view.layers["hands"].append(view.nodes["/hands/points"])
    _add_gui(server, view, config)
    _aim_camera(server, view, twin_dir, articulation)
    return view


def _add_gui(server: Any, view: TwinView, config: ViewConfig) -> None:
    with server.gui.add_folder("Replay"):
        view.time_slider = server.gui.add_slider("frame", min=0, max=max(len(view.T_world_camera) - 1, 1), step=1,
                                                 initial_value=0)
        view.time_slider.on_update(lambda _event: view.set_frame(int(view.time_slider.value)))
    with server.gui.add_folder("Joints"):
        for name, part in view.parts.items():
            lower, upper = part.state_range
            slider = server.gui.add_slider(
                f"{name} ({part.joint_type}, {'rad' if part.joint_type == 'revolute' else 'm'})",
                min=float(lower), max=float(max(upper, lower + 1e-6)),
                step=float(max(upper - lower, 1e-6)) / config.slider_steps, initial_value=float(np.clip(0.0, lower, upper)),
            )
            slider.on_update(lambda _event, name=name, slider=slider: view.set_state(name, slider.value))
            view.sliders[name] = slider
            view.set_state(name, slider.value)
    with server.gui.add_folder("Layers"):
        for layer in LAYERS:
            if not view.layers[layer]:
                continue
            box = server.gui.add_checkbox(layer, initial_value=True)
            box.on_update(lambda _event, layer=layer, box=box: view.set_layer(layer, box.value))
            view.checkboxes[layer] = box
    view.set_frame(0)


def serve_twin(
    twin_dir: str | Path,
    host: str = "127.0.0.1",
    port: int = 8080,
    config: ViewConfig = ViewConfig(),  # noqa: B008 (frozen, immutable default)
    on_ready: Callable[[str], None] | None = None,
    capture_dir: str | Path | None = None,
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
        build_twin_view(server, twin_dir, config, capture_dir)
        if on_ready is not None:
            on_ready(f"http://{host}:{port}")
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()


__all__ = ["INSTALL_HINT", "LAYERS", "TwinView", "ViewConfig", "build_twin_view", "frustum_segments", "import_viser", "serve_twin"]
