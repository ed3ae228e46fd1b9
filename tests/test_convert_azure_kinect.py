"""Azure Kinect converter on the real recording in shared/realdata: calibration, registration of depth into
the colour camera (checked on a synthetic step scene and against the real colour edges), refusal of videos."""

from __future__ import annotations

from pathlib import Path

import av
import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from funrec.convert import ConvertConfig, convert, detect_format
from funrec.convert.azure_kinect import parse_calibration
from funrec.convert.registration import register_depth
from funrec.errors import CaptureError
from funrec.formats.capture import load_capture
from funrec.geometry.camera import backproject

MKV = Path("/work/shared/realdata/azure_kinect_mkv/recording.mkv")
CALIBRATION = MKV.with_name("calibration.json")
needs_real_data = pytest.mark.skipif(not MKV.is_file(), reason=f"real data not present at {MKV}")


@pytest.fixture(scope="module")
def calibration():
    if not CALIBRATION.is_file():
        pytest.skip("real calibration not present")
    return parse_calibration(CALIBRATION, CALIBRATION.read_text(), "NFOV_UNBINNED", 720)


def test_mode_specific_intrinsics_follow_the_sdk(calibration):
    # ModelParameters start cx cy fx fy, unitised by the 1024 sensor; NFOV unbinned crops (192, 180); -0.5
    # moves the origin from the pixel corner to the pixel centre (the SDK's pixelised zero-centred output).
    depth, colour = calibration.depth, calibration.colour
    assert depth.size == (640, 576) and colour.size == (1280, 720)
    assert depth.K[0, 0] == pytest.approx(0.4927808940410614 * 1024)  # 504.6 px, the NFOV focal length
    assert depth.K[0, 2] == pytest.approx(0.51296979188919067 * 1024 - 192 - 0.5)
    assert depth.K[1, 2] == pytest.approx(0.51692354679107666 * 1024 - 180 - 0.5)
    # Colour 720p is the 4096x3072 calibration binned to 1280x960 and cropped by 120 rows.
    assert colour.K[1, 2] == pytest.approx(0.50661760568618774 * 960 - 120 - 0.5)
    # ModelParameters order ends with p2, p1; OpenCV wants k1 k2 p1 p2 k3 k4 k5 k6.
    np.testing.assert_allclose(depth.distortion[2:4], [2.0557534298859537e-5, -7.2104157879948616e-5])
    # The colour camera sits about 32 mm beside the depth camera, tilted by about 6 degrees.
    assert np.linalg.norm(calibration.T_colour_depth[:3, 3]) == pytest.approx(0.0324, abs=5e-4)
    angle = np.degrees(np.linalg.norm(Rotation.from_matrix(calibration.T_colour_depth[:3, :3]).as_rotvec()))
    assert angle == pytest.approx(4.95, abs=0.1)


def test_registration_of_a_step_scene_lands_on_the_true_depths(calibration):
    """A scene defined in the colour frame: a board at Z = 0.5 m covering X < 0, a wall at Z = 1 m. Depth
    is ray-cast from the depth camera through its distorted pixels, then registered into the colour image."""
    xy, valid = calibration.depth.rays()
    T_colour_depth = calibration.T_colour_depth
    o_colour = T_colour_depth[:3, 3]
    d_colour = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ T_colour_depth[:3, :3].T
    s_board = (0.5 - o_colour[2]) / d_colour[:, 2]  # ray parameter = depth-camera z (ray z component is 1)
    hits_board = (o_colour[0] + s_board * d_colour[:, 0]) < 0
    s_wall = (1.0 - o_colour[2]) / d_colour[:, 2]
    depth_m = np.where(hits_board, s_board, s_wall).reshape(576, 640)
    K = calibration.colour.K
    registered = register_depth(depth_m, xy, valid, T_colour_depth, K, (1280, 720), splat_2x2=True)
    u = np.arange(1280)
    # Columns up to 300 px either side of the board edge and these rows are inside the depth camera's view.
    board = (u < K[0, 2] - 1.5) & (u > K[0, 2] - 300)
    wall = (u > K[0, 2] + 1.5) & (u < K[0, 2] + 300)
    rows = slice(200, 520)
    on_board = registered[rows][:, board]
    on_wall = registered[rows][:, wall]
    np.testing.assert_allclose(on_board[on_board > 0], 0.5, atol=1e-9)
    # Wall pixels are at 1 m, or 0 in the board's shadow as seen from the depth camera (it is left of the colour camera).
    assert set(np.unique(np.round(on_wall, 9))) <= {0.0, 1.0}
    assert (on_board > 0).mean() > 0.999 and (on_wall > 0).mean() > 0.9


def _edge_fit(rgb: np.ndarray, depth_m: np.ndarray, max_shift: int = 8) -> np.ndarray:
    """Mean distance (px, clipped at 10) from depth discontinuities (> 3 cm between neighbours) to the
    nearest colour edge, for every shift of the depth edges by (dx, dy) in [-max_shift, max_shift]."""
    edges = np.zeros(depth_m.shape, bool)
    for axis in (0, 1):
        other = np.roll(depth_m, -1, axis=axis)
        edges |= (depth_m > 0) & (other > 0) & (np.abs(depth_m - other) > 0.03)
    grey = cv2.GaussianBlur(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), (5, 5), 0)
    colour_edges = cv2.Canny(grey, 30, 90) > 0
    distance = np.minimum(cv2.distanceTransform((~colour_edges).astype(np.uint8), cv2.DIST_L2, 5), 10.0)
    v, u = np.nonzero(edges)
    H, W = depth_m.shape
    n = 2 * max_shift + 1
    fit = np.zeros((n, n))
    for dy in range(-max_shift, max_shift + 1):
        for dx in range(-max_shift, max_shift + 1):
            fit[dy + max_shift, dx + max_shift] = distance[np.clip(v + dy, 0, H - 1), np.clip(u + dx, 0, W - 1)].mean()
    return fit


def write_overlay(capture_dir: Path, path: Path) -> None:
    """Colour with colour edges (cyan) and depth edges (red), beside the coloured point cloud seen from a
    camera turned by 12 degrees about a point 0.6 m ahead."""
    capture = load_capture(capture_dir)
    rgb, depth_m, K = capture.rgb(0), capture.depth_m(0), capture.intrinsics.K
    H, W = depth_m.shape
    overlay = rgb.copy()
    grey = cv2.GaussianBlur(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), (5, 5), 0)
    colour_edges = cv2.Canny(grey, 30, 90) > 0
    overlay[colour_edges] = (0.4 * overlay[colour_edges] + [0, 120, 153]).astype(np.uint8)
    jump = np.zeros((H, W), bool)
    for axis in (0, 1):
        other = np.roll(depth_m, -1, axis=axis)
        jump |= (depth_m > 0) & (other > 0) & (np.abs(depth_m - other) > 0.03)
    overlay[jump] = [255, 0, 0]
    p_camera = backproject(depth_m, K)
    ok = np.isfinite(p_camera[:, 2])
    centre = np.array([0.0, 0.0, 0.6])
    R = Rotation.from_euler("yx", [-12, 6], degrees=True).as_matrix()
    p_view = (p_camera[ok] - centre) @ R.T + centre
    colours = rgb.reshape(-1, 3)[ok]
    view = np.zeros_like(rgb)
    order = np.argsort(-p_view[:, 2])  # far first, so near points overwrite them
    u = np.floor(K[0, 0] * p_view[order, 0] / p_view[order, 2] + K[0, 2]).astype(int)
    v = np.floor(K[1, 1] * p_view[order, 1] / p_view[order, 2] + K[1, 2]).astype(int)
    for du in (0, 1):
        for dv in (0, 1):
            inside = (u + du >= 0) & (u + du < W) & (v + dv >= 0) & (v + dv < H)
            view[v[inside] + dv, u[inside] + du] = colours[order][inside]
    image = np.concatenate([overlay, np.full((H, 8, 3), 255, np.uint8), view], axis=1)
    cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    if not MKV.is_file():
        pytest.skip(f"real data not present at {MKV}")
    out = tmp_path_factory.mktemp("azure") / "capture"
    return convert(MKV, out), out


@needs_real_data
def test_real_recording_converts_at_colour_resolution(converted, calibration, tmp_path):
    report, out = converted
    assert detect_format(MKV) == "azure_kinect"
    capture = load_capture(out)
    K = capture.intrinsics
    assert len(capture) == 1 and report.dropped == ()
    assert (K.width, K.height, K.depth_scale) == (1280, 720, 1000.0)
    np.testing.assert_allclose(K.K, calibration.colour.K)
    depth_m = capture.depth_m(0)
    assert 0.4 < (depth_m > 0).mean() < 0.7  # NFOV covers about half of the 90-degree colour view
    # A known pixel: raw depth-image pixel (400, 300), moved by the calibration, is in the capture at its
    # colour pixel with its colour-frame z (1 mm quantisation).
    with av.open(str(MKV)) as container:
        stream = next(s for s in container.streams if s.metadata.get("title") == "DEPTH")
        raw = np.frombuffer(bytes(next(p for p in container.demux(stream) if p.size)), ">u2").reshape(576, 640)
    xy, valid = calibration.depth.rays()
    k = 300 * 640 + 400
    assert valid[k] and raw[300, 400] > 0
    p_depth = np.append(xy[k], 1.0) * raw[300, 400] / 1000
    p_colour = calibration.T_colour_depth[:3, :3] @ p_depth + calibration.T_colour_depth[:3, 3]
    uv = (K.K @ p_colour)[:2] / p_colour[2]
    window = depth_m[int(uv[1]) : int(uv[1]) + 2, int(uv[0]) : int(uv[0]) + 2]
    assert np.min(np.abs(window - p_colour[2])) < 0.0011
    write_overlay(out, tmp_path / "azure_overlay.png")
    assert (tmp_path / "azure_overlay.png").stat().st_size > 0


@needs_real_data
def test_depth_edges_fit_colour_edges_best_without_shift(converted, calibration):
    """Measured: mean depth-edge to colour-edge distance 2.89 px unshifted, minimum 2.76 px at a shift of
    (-1, +1) px, 4.24 px averaged over shifts of up to 8 px. Registering with the extrinsics ignored puts
    the optimum far away (the mug at 0.3 m moves by ~60 px for the 32 mm baseline)."""
    _, out = converted
    capture = load_capture(out)
    rgb, depth_m = capture.rgb(0), capture.depth_m(0)
    fit = _edge_fit(rgb, depth_m)
    best = np.array(np.unravel_index(fit.argmin(), fit.shape)) - 8
    assert np.all(np.abs(best) <= 2), best
    assert fit[8, 8] < 0.75 * fit.mean(), (fit[8, 8], fit.mean())
    # Negative control: the same depth registered with only the rotation (translation dropped) fits worse.
    with av.open(str(MKV)) as container:
        stream = next(s for s in container.streams if s.metadata.get("title") == "DEPTH")
        raw = np.frombuffer(bytes(next(p for p in container.demux(stream) if p.size)), ">u2").reshape(576, 640)
    xy, valid = calibration.depth.rays()
    T_wrong = calibration.T_colour_depth.copy()
    T_wrong[:3, 3] = 0.0
    wrong = register_depth(raw / 1000, xy, valid, T_wrong, capture.intrinsics.K, (1280, 720), True)
    assert _edge_fit(rgb, wrong)[8, 8] > fit[8, 8] + 0.5


@needs_real_data
def test_downscaled_output(tmp_path, calibration):
    report = convert(MKV, tmp_path / "small", ConvertConfig(output_width=640))
    capture = load_capture(tmp_path / "small")
    K = capture.intrinsics
    assert (K.width, K.height) == (640, 360)
    assert K.fx == pytest.approx(calibration.colour.K[0, 0] / 2)
    assert K.cx == pytest.approx((calibration.colour.K[0, 2] + 0.5) / 2 - 0.5)
    assert any("shrunk to 640x360" in n for n in report.notes)
    assert 0.4 < (capture.depth_m(0) > 0).mean() < 0.7


def test_plain_videos_are_refused(tmp_path):
    mp4 = tmp_path / "walkthrough.mp4"
    writer = cv2.VideoWriter(str(mp4), cv2.VideoWriter_fourcc(*"mp4v"), 10, (64, 48))
    for k in range(3):
        writer.write(np.full((48, 64, 3), 40 * k, np.uint8))
    writer.release()
    with pytest.raises(CaptureError, match=r"walkthrough.mp4: a plain video has no depth.*Azure Kinect .mkv"):
        convert(mp4, tmp_path / "capture")
    with pytest.raises(CaptureError, match="a plain video has no depth"):
        convert(mp4, tmp_path / "capture", ConvertConfig(format="azure_kinect"))
    mkv = tmp_path / "phone.mkv"  # a Matroska video without the Azure Kinect depth track
    with av.open(str(mkv), "w") as container:
        stream = container.add_stream("mjpeg", rate=10)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuvj420p"
        for k in range(3):
            frame = av.VideoFrame.from_ndarray(np.full((48, 64, 3), 40 * k, np.uint8), format="rgb24")
            container.mux(stream.encode(frame))
        container.mux(stream.encode())
    with pytest.raises(CaptureError, match=r"phone.mkv: no DEPTH track.*a plain video has no depth"):
        convert(mkv, tmp_path / "capture")
    assert not (tmp_path / "capture").exists()

