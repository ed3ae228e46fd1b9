"""Tests of funrec.view: a viser server on a free port shows a hand-written twin, and a joint
slider moves its part by the joint transform."""

from __future__ import annotations

import urllib.request
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from funrec.geometry.joints import joint_transform
from funrec.geometry.transforms import make_transform
from tests.helpers.view_twin import AXIS, PIVOT, free_port, write_view_twin

viser = pytest.importorskip("viser")

from funrec.view import ViewConfig, build_twin_view  # noqa: E402 (after the skip)

# Node poses are float64 quaternions and positions; a matrix -> quaternion -> matrix round trip
# costs ~1e-15, so 1e-9 means "the same pose".
EXACT = 1e-9


@pytest.fixture()
def twin(tmp_path: Path) -> Path:
    return write_view_twin(tmp_path)


def test_viewer_shows_the_twin_and_sliders_move_parts(twin: Path) -> None:
    port = free_port()
    server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    try:
        view = build_twin_view(server, twin, ViewConfig(frustum_every=10))
        # The server answers over HTTP with the viewer page.
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10) as response:
            assert response.status == 200
        assert set(view.part_nodes) == {"part_0", "part_1"} and set(view.sliders) == {"part_0", "part_1"}
        expected = {"/static", "/camera_path", "/cameras", "/current_camera",
                    "/parts/part_0/mesh", "/parts/part_1/mesh", "/parts/part_0/contact", "/parts/part_0/grasp"}
        assert expected <= set(view.nodes), sorted(view.nodes)
        assert "/parts/part_1/contact" not in view.nodes  # never held: no contact drawn
        slider = view.sliders["part_0"]
        assert (slider.min, slider.max, slider.value) == pytest.approx((0.0, 1.2, 0.0))
        node = view.part_nodes["part_0"]
        np.testing.assert_allclose(node.position, 0.0, atol=EXACT)  # canonical state: identity pose
        slider.value = 0.6
        T = joint_transform("revolute", AXIS, PIVOT, 0.6)
        R = Rotation.from_quat(np.asarray(node.wxyz)[[1, 2, 3, 0]]).as_matrix()
        np.testing.assert_allclose(R, T[:3, :3], atol=EXACT)
        np.testing.assert_allclose(node.position, T[:3, 3], atol=EXACT)
        view.sliders["part_1"].value = 0.2
        np.testing.assert_allclose(view.part_nodes["part_1"].position, [0.0, -0.2, 0.0], atol=EXACT)
    finally:
        server.stop()


def test_time_slider_replays_layers_toggle_and_camera_aims_at_parts(twin: Path) -> None:
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        view = build_twin_view(server, twin, ViewConfig(frustum_every=10))
        # Frustums are line segments (8 per drawn pose), never filled shapes.
        assert np.asarray(view.nodes["/cameras"].points).shape == (3 * 8, 2, 3)
        view.time_slider.value = 6  # part_0 tracked at 5, 6, 7 with states 0, 0.4, 1.2
        assert view.sliders["part_0"].value == pytest.approx(0.4)
        T = joint_transform("revolute", AXIS, PIVOT, 0.4)
        np.testing.assert_allclose(view.part_nodes["part_0"].position, T[:3, 3], atol=EXACT)
        np.testing.assert_allclose(view.nodes["/current_camera"].position, [0.3, 0.0, -1.0], atol=EXACT)
        view.time_slider.value = 29  # after the last tracked frame a part holds its last state
        assert view.sliders["part_0"].value == pytest.approx(1.2) and view.sliders["part_1"].value == pytest.approx(0.25)
        assert set(view.checkboxes) == {"camera path", "frustums", "contacts"}  # no capture: no hand layer
        view.checkboxes["frustums"].value = False
        assert not view.nodes["/cameras"].visible and not view.nodes["/current_camera"].visible
        assert view.nodes["/camera_path"].visible
        view.checkboxes["contacts"].value = False
        assert not view.nodes["/parts/part_0/contact"].visible
        # The start camera looks at the middle of the parts (door centre and drawer centre).
        look_at = np.asarray(server.initial_camera.look_at)
        assert np.linalg.norm(look_at - [0.15, 0.475, 0.25]) < 0.02, look_at
    finally:
        server.stop()


def test_frustum_segments_reach_the_image_corners() -> None:
    from funrec.view import frustum_segments

    K = np.array([[100.0, 0.0, 40.0], [0.0, 100.0, 30.0], [0.0, 0.0, 1.0]])
    T = make_transform(np.eye(3), [1.0, 2.0, 3.0])
    segments = frustum_segments(T[None], K, 80, 60, depth=0.5)
    assert segments.shape == (8, 2, 3)
    np.testing.assert_allclose(segments[:4, 0], np.tile([1.0, 2.0, 3.0], (4, 1)))  # from the apex
    np.testing.assert_allclose(segments[0, 1], [1.0 - 0.2, 2.0 - 0.15, 3.5])  # to the top-left corner at depth 0.5


def test_missing_twin_file_names_it(tmp_path: Path) -> None:
    from funrec.errors import FormatError

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        with pytest.raises(FormatError, match=r"articulation\.json"):
            build_twin_view(server, tmp_path)
    finally:
        server.stop()


def test_big_static_mesh_is_decimated_keeping_colours() -> None:
    from funrec.view import _decimated

    sphere = trimesh.creation.icosphere(subdivisions=5)  # 20480 triangles
    sphere.visual.vertex_colors = np.tile([200, 30, 30, 255], (len(sphere.vertices), 1))
    small = _decimated(sphere, 2000)
    assert len(small.faces) <= 2000 and abs(small.area - sphere.area) / sphere.area < 0.02
    assert np.abs(np.asarray(small.visual.vertex_colors)[:, :3].astype(int) - [200, 30, 30]).max() <= 2
    assert _decimated(sphere, 0) is sphere
