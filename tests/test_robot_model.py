"""The project robot's MJCF and URDF come from one source and agree: files, kinematics, limits, masses."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from funrec_robot.funrec_mm import NAME, funrec_mm_tree, write_funrec_mm
from funrec_robot.kinematic_tree import Geom, Inertial, Joint, KinematicTree, Link
from funrec_robot.robot import load_robot

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
FK_ATOL_M = 1e-6
"""FK agreement asked of the two files, m (and rad for rotation-matrix entries). Both write 12
significant digits, so anything above ~1e-10 is a modelling difference, not rounding."""


@pytest.fixture(scope="module")
def mj_model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(ROBOTS / NAME / f"{NAME}.xml"))


@pytest.fixture(scope="module")
def pin_model() -> pin.Model:
    return pin.buildModelFromUrdf(str(ROBOTS / NAME / f"{NAME}.urdf"))


def test_committed_files_match_the_generator(tmp_path: Path) -> None:
    generated = write_funrec_mm(tmp_path)
    for path in generated:
        committed = ROBOTS / path.relative_to(tmp_path)
        assert committed.read_text() == path.read_text(), (
            f"{committed} differs from funrec_robot/funrec_mm.py; run `python -m funrec_robot.funrec_mm`"
        )


def _pin_configuration(pin_model: pin.Model, mj_model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    q = np.zeros(pin_model.nq)
    for joint_id in range(1, pin_model.njoints):
        q[pin_model.joints[joint_id].idx_q] = qpos[mj_model.joint(pin_model.names[joint_id]).qposadr[0]]
    return q


@settings(deadline=None, max_examples=60)
@given(fractions=hnp.arrays(np.float64, 12, elements=st.floats(0.0, 1.0)))
def test_fk_agrees_between_mujoco_and_pinocchio(mj_model, pin_model, fractions: np.ndarray) -> None:
    assert mj_model.nq == pin_model.nq == fractions.size
    low, high = mj_model.jnt_range[:, 0], mj_model.jnt_range[:, 1]
    qpos = low + fractions[mj_model.jnt_qposadr] * (high - low)
    data = mujoco.MjData(mj_model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(mj_model, data)
    pin_data = pin_model.createData()
    pin.framesForwardKinematics(pin_model, pin_data, _pin_configuration(pin_model, mj_model, qpos))
    # Every body origin (URDF link of the same name) and the grasp site.
    for body in range(1, mj_model.nbody):
        T_world_link = pin_data.oMf[pin_model.getFrameId(mj_model.body(body).name)]
        np.testing.assert_allclose(T_world_link.translation, data.xpos[body], atol=FK_ATOL_M)
        np.testing.assert_allclose(T_world_link.rotation, data.xmat[body].reshape(3, 3), atol=FK_ATOL_M)
    T_world_grasp = pin_data.oMf[pin_model.getFrameId("grasp_site")]
    np.testing.assert_allclose(T_world_grasp.translation, data.site("grasp_site").xpos, atol=FK_ATOL_M)
    np.testing.assert_allclose(T_world_grasp.rotation, data.site("grasp_site").xmat.reshape(3, 3), atol=FK_ATOL_M)


def test_limits_agree_between_urdf_mjcf_and_yaml(mj_model, pin_model) -> None:
    robot = load_robot(ROBOTS / f"{NAME}.yaml")
    tree = funrec_mm_tree()
    for name in tree.joint_names:
        joint = tree.joint(name)
        mj = mj_model.joint(name)
        pin_id = pin_model.getJointId(name)
        iq = pin_model.joints[pin_id].idx_q
        np.testing.assert_allclose(mj_model.jnt_range[mj.id], [joint.lower, joint.upper], rtol=1e-12)
        np.testing.assert_allclose(
            [pin_model.lowerPositionLimit[iq], pin_model.upperPositionLimit[iq]], [joint.lower, joint.upper], rtol=1e-12
        )
        np.testing.assert_allclose(mj_model.jnt_actfrcrange[mj.id], [-joint.effort, joint.effort], rtol=1e-12)
        assert pin_model.effortLimit[iq] == pytest.approx(joint.effort, rel=1e-12)
        assert pin_model.velocityLimit[iq] == pytest.approx(joint.velocity, rel=1e-12)
    for i, name in enumerate(robot.joint_names):
        joint = tree.joint(name)
        assert (robot.q_min[i], robot.q_max[i]) == pytest.approx((joint.lower, joint.upper), rel=1e-12)
        assert robot.v_max[i] == pytest.approx(joint.velocity, rel=1e-12)
        assert robot.a_max[i] == pytest.approx(joint.acceleration, rel=1e-12)
        assert robot.effort_max[i] == pytest.approx(joint.effort, rel=1e-12)
    for actuator in range(mj_model.nu):
        joint = mj_model.actuator_trnid[actuator, 0]
        np.testing.assert_allclose(mj_model.actuator_ctrlrange[actuator], mj_model.jnt_range[joint])
        np.testing.assert_allclose(mj_model.actuator_forcerange[actuator], mj_model.jnt_actfrcrange[joint])


def test_masses_and_inertias_agree(mj_model, pin_model) -> None:
    data = mujoco.MjData(mj_model)
    mujoco.mj_forward(mj_model, data)
    pin_data = pin_model.createData()
    q = _pin_configuration(pin_model, mj_model, data.qpos)
    assert pin.computeTotalMass(pin_model) == pytest.approx(mj_model.body_subtreemass[0], rel=1e-12)
    np.testing.assert_allclose(pin.centerOfMass(pin_model, pin_data, q), data.subtree_com[0], atol=1e-9)
    # Joint-space inertia without MuJoCo's armature, which URDF cannot carry.
    M_mujoco = np.zeros((mj_model.nv, mj_model.nv))
    mujoco.mj_fullM(mj_model, data, M_mujoco)
    M_mujoco -= np.diag(mj_model.dof_armature)
    np.testing.assert_allclose(pin.crba(pin_model, pin_data, q), M_mujoco, atol=1e-9)


def test_robot_is_plausible(mj_model) -> None:
    data = mujoco.MjData(mj_model)
    mujoco.mj_forward(mj_model, data)
    base_geom = mj_model.geom("base_link_geom0")
    assert 2.0 * base_geom.size[:2] == pytest.approx([0.5, 0.5])  # footprint, m
    assert 60.0 < mj_model.body_subtreemass[0] < 90.0  # kg, a small indoor mobile manipulator
    arm_mass = sum(mj_model.body_mass[mj_model.body(f"arm_link{i}").id] for i in range(1, 8))
    assert arm_mass == pytest.approx(6.491, abs=1e-3)  # Kinova Gen3 7-DoF links
    assert data.ncon == 0  # no self-contact when straight
    assert mj_model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST


def test_tree_rejects_inconsistent_descriptions() -> None:
    good = Joint("j", "revolute", (0.0, 0.0, 1.0), -1.0, 1.0, velocity=1.0, acceleration=1.0, effort=1.0)
    with pytest.raises(ValueError, match="not a unit vector"):
        Joint("j", "revolute", (0.0, 0.0, 2.0), -1.0, 1.0, velocity=1.0, acceleration=1.0, effort=1.0)
    with pytest.raises(ValueError, match="lower 1.0 must be below upper -1.0"):
        Joint("j", "revolute", (0.0, 0.0, 1.0), 1.0, -1.0, velocity=1.0, acceleration=1.0, effort=1.0)
    root = Link("root", None)
    with pytest.raises(ValueError, match="needs an Inertial"):
        KinematicTree("t", (root, Link("arm", "root", joints=(good,), geoms=(Geom("sphere", (0.1,)),))))
    with pytest.raises(ValueError, match="parent 'missing' must come before it"):
        KinematicTree("t", (root, Link("arm", "missing", inertial=Inertial(1.0, (0, 0, 0), (1, 1, 1)))))
