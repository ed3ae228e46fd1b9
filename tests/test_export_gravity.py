"""Passive parts hold still under gravity in every export: twin.urdf in pybullet, twin.xml in
MuJoCo and twin.usda (read with pxr, simulated in MuJoCo), each part at three states across its
range for 2 s, with its joint axis tilted 5.35 degrees off vertical or horizontal (what the smoke
demo's door axis was). Joint friction holds them, not springs (ExportConfig.friction_gravity_margin).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from funrec.export.sim_model import gravity_load
from funrec.export.simulation import ExportConfig, export_simulation
from tests.gravity_hold import HOLD_SECONDS, STATE_FRACTIONS, hold_mjcf, hold_urdf, hold_usd
from tests.helpers.twins import FAST_EXPORT, T_WORLD_CABINET, write_cabinet_twin

HOLD_POSITION_MM = 1.0
HOLD_ANGLE_DEG = 0.1
TILT_DEG = 5.35
"""Axis error of the smoke demo's door at f1568f6: enough to slam a frictionless door shut."""


def _tilted_export(twin_dir: Path, config: ExportConfig) -> ExportConfig:
    """The cabinet upright (z up), then tilted by TILT_DEG about x (across the front), so the door
    axis is TILT_DEG off vertical and the drawer axis off horizontal."""
    write_cabinet_twin(twin_dir)
    T_tilt = np.eye(4)
    T_tilt[:3, :3] = Rotation.from_rotvec(np.radians(TILT_DEG) * np.array([1.0, 0.0, 0.0])).as_matrix()
    return dataclasses.replace(config, T_export_world=T_tilt @ np.linalg.inv(T_WORLD_CABINET))


@pytest.fixture(scope="module")
def tilted_twin(tmp_path_factory: pytest.TempPathFactory) -> Path:
    twin_dir = tmp_path_factory.mktemp("gravity") / "twin"
    export_simulation(twin_dir, _tilted_export(twin_dir, FAST_EXPORT))
    return twin_dir


@pytest.mark.parametrize("simulator", ["urdf", "mjcf", "usd"])
def test_parts_hold_still_under_gravity(tilted_twin: Path, simulator: str) -> None:
    if simulator == "urdf":
        pytest.importorskip("pybullet")
        drifts = hold_urdf(tilted_twin / "twin.urdf")
    elif simulator == "mjcf":
        drifts = hold_mjcf(tilted_twin / "twin.xml")
    else:
        drifts = hold_usd(tilted_twin / "twin.usda")
    parts = [d for d in drifts if d.part != "base"]
    assert sorted({d.part for d in parts}) == ["part_0", "part_1"]
    assert len(parts) == 2 * len(STATE_FRACTIONS)
    for d in drifts:
        assert d.position_mm < HOLD_POSITION_MM and d.angle_deg < HOLD_ANGLE_DEG, (
            f"{d.simulator}: {d.part} set to {d.state:.3f} moved {d.position_mm:.3f} mm, {d.angle_deg:.4f} deg in {HOLD_SECONDS} s"
        )


def test_without_friction_the_tilted_parts_do_move(tmp_path: Path) -> None:
    """The check above can fail: with no friction gravity swings the door and runs the drawer out."""
    twin_dir = tmp_path / "twin"
    frictionless = dataclasses.replace(
        FAST_EXPORT, formats=("mjcf",), friction_gravity_margin=0.0, revolute_friction_nm=0.0, prismatic_friction_n=0.0
    )
    export_simulation(twin_dir, _tilted_export(twin_dir, frictionless))
    drifts = hold_mjcf(twin_dir / "twin.xml")
    assert all(d.position_mm > 10.0 for d in drifts)


def test_friction_covers_the_gravity_load(tilted_twin: Path) -> None:
    exports = export_simulation(tilted_twin, _tilted_export(tilted_twin, dataclasses.replace(FAST_EXPORT, formats=())))
    for link, joint in zip(exports.model.parts, exports.model.joints):
        load = gravity_load(link, joint, np.array([0.0, 0.0, -9.81]))
        assert load > 0.0
        assert joint.friction == pytest.approx(max(FAST_EXPORT.friction_gravity_margin * load,
                                                   FAST_EXPORT.revolute_friction_nm if joint.joint_type == "revolute"
                                                   else FAST_EXPORT.prismatic_friction_n))
    # The drawer pulled along a 5.35 degree slope: m g sin(tilt) along its axis.
    drawer_link, drawer = exports.model.parts[1], exports.model.joints[1]
    expected = drawer_link.mass.mass_kg * 9.81 * abs(drawer.T_parent_joint[2, 2])
    assert gravity_load(drawer_link, drawer, np.array([0.0, 0.0, -9.81])) == pytest.approx(expected)


def test_axis_snapping_levels_the_tilted_axes(tmp_path: Path) -> None:
    twin_dir = tmp_path / "twin"
    config = _tilted_export(twin_dir, dataclasses.replace(FAST_EXPORT, formats=(), snap_axis_deg=6.0))
    door, drawer = export_simulation(twin_dir, config).model.joints
    np.testing.assert_allclose(abs(door.T_parent_joint[2, 2]), 1.0, atol=1e-12)  # hinge along gravity
    np.testing.assert_allclose(drawer.T_parent_joint[2, 2], 0.0, atol=1e-12)  # runner level
    # Nothing left for friction to hold: the least friction remains.
    assert (door.friction, drawer.friction) == (FAST_EXPORT.revolute_friction_nm, FAST_EXPORT.prismatic_friction_n)
    # Beyond the tolerance nothing is snapped.
    door, drawer = export_simulation(twin_dir, dataclasses.replace(config, snap_axis_deg=5.0)).model.joints
    assert abs(door.T_parent_joint[2, 2]) < 1.0 - 1e-6 and abs(drawer.T_parent_joint[2, 2]) > 1e-6


def test_snap_axis() -> None:
    from funrec.export.axis_snap import snap_axis

    tilted = np.array([np.sin(np.radians(3.0)), 0.0, -np.cos(np.radians(3.0))])
    np.testing.assert_allclose(snap_axis(tilted, 4.0)[0], [0.0, 0.0, -1.0])
    assert snap_axis(tilted, 2.0)[1] == "none" and snap_axis(tilted, 0.0)[1] == "none"
    level, kind = snap_axis(np.array([0.0, 2.0, 0.1]), 4.0)
    assert kind == "horizontal"
    np.testing.assert_allclose(level, [0.0, 1.0, 0.0])
