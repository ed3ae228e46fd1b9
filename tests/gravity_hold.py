"""Passive parts under gravity in three simulators: twin.urdf in pybullet, twin.xml in MuJoCo and
twin.usda read with pxr and simulated in MuJoCo. Each part is set to a state, left alone for a
while under gravity, and its drift from where it was set is measured.

Used by tests/test_export_gravity.py; run on a twin folder to print the numbers:
``python tests/gravity_hold.py TWIN``.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

GRAVITY_M_S2 = 9.81
HOLD_SECONDS = 2.0
"""Simulated time each part is left alone."""
STATE_FRACTIONS = (0.1, 0.5, 0.9)
"""Where in its range [lower, upper] each part is set: three states across the range."""
PYBULLET_DT = 1.0 / 240.0
"""pybullet's default time step (s)."""


@dataclass(frozen=True)
class Drift:
    """How far a part moved when left alone at one state."""

    simulator: str
    part: str
    state: float
    """Joint state it was set to (rad or m)."""
    position_mm: float
    """Largest displacement of a point of the part's bounding box (mm)."""
    angle_deg: float
    """Rotation of the part (degrees)."""


def _move(T_start: np.ndarray, T_end: np.ndarray, corners_link: np.ndarray) -> tuple[float, float]:
    """(largest corner displacement in mm, rotation in degrees) between two link poses."""
    p_start = corners_link @ T_start[:3, :3].T + T_start[:3, 3]
    p_end = corners_link @ T_end[:3, :3].T + T_end[:3, 3]
    angle = Rotation.from_matrix(T_end[:3, :3] @ T_start[:3, :3].T).magnitude()
    return float(np.linalg.norm(p_end - p_start, axis=1).max() * 1e3), float(np.degrees(angle))


def _states(lower: float, upper: float) -> list[float]:
    return [lower + f * (upper - lower) for f in STATE_FRACTIONS]


def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def hold_mujoco(model, simulator: str) -> list[Drift]:  # noqa: ANN001 - mujoco.MjModel
    """Each hinge/slide joint of a MuJoCo model at three states, the others at 0, for HOLD_SECONDS."""
    import mujoco

    drifts = []
    for j in range(model.njnt):
        if int(model.jnt_type[j]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            continue
        body = int(model.jnt_bodyid[j])
        geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body]
        # Corners of the box around the body's geoms (their bounding spheres), body frame.
        lo = np.min([model.geom_pos[g] - model.geom_rbound[g] for g in geoms], axis=0)
        hi = np.max([model.geom_pos[g] + model.geom_rbound[g] for g in geoms], axis=0)
        corners = _box_corners(lo, hi)
        lower, upper = model.jnt_range[j]
        for state in _states(lower, upper):
            data = mujoco.MjData(model)
            data.qpos[model.jnt_qposadr[j]] = state
            mujoco.mj_forward(model, data)
            T_start = _pose(data.xpos[body], data.xmat[body])
            for _ in range(int(round(HOLD_SECONDS / model.opt.timestep))):
                mujoco.mj_step(model, data)
            position_mm, angle_deg = _move(T_start, _pose(data.xpos[body], data.xmat[body]), corners)
            drifts.append(Drift(simulator, model.joint(j).name, float(state), position_mm, angle_deg))
    return drifts


def _pose(position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.asarray(rotation).reshape(3, 3)
    T[:3, 3] = position
    return T


def hold_mjcf(path: Path) -> list[Drift]:
    import mujoco

    return hold_mujoco(mujoco.MjModel.from_xml_path(str(path)), "mujoco (twin.xml)")


def hold_urdf(path: Path) -> list[Drift]:
    """twin.urdf in pybullet (DIRECT, no useFixedBase: the world link fixes it). Joint friction is
    what pybullet's manual prescribes: a velocity motor at 0 whose force limit is the friction,
    here the URDF's ``<dynamics friction>``; pybullet applies the URDF damping itself."""
    import pybullet as p

    client = p.connect(p.DIRECT)
    try:
        p.setGravity(0.0, 0.0, -GRAVITY_M_S2, physicsClientId=client)
        p.setTimeStep(PYBULLET_DT, physicsClientId=client)
        body = p.loadURDF(str(path), flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
        base_start = p.getBasePositionAndOrientation(body, physicsClientId=client)
        joints = [p.getJointInfo(body, i, physicsClientId=client) for i in range(p.getNumJoints(body, physicsClientId=client))]
        moving = [info for info in joints if info[2] in (p.JOINT_REVOLUTE, p.JOINT_PRISMATIC)]
        drifts = []
        for info in moving:
            index, name, lower, upper = info[0], info[1].decode(), info[8], info[9]
            lo, hi = (np.array(v) for v in p.getAABB(body, index, physicsClientId=client))
            for state in _states(lower, upper):
                for other in moving:
                    p.resetJointState(body, other[0], state if other[0] == index else 0.0, 0.0, physicsClientId=client)
                    p.setJointMotorControl2(body, other[0], p.VELOCITY_CONTROL, targetVelocity=0.0, force=other[7],
                                            physicsClientId=client)
                T_start = _link_pose(p, body, index, client)
                # The box corners in the link frame, from the world-frame AABB at this state.
                corners_world = _box_corners(lo, hi)
                corners_link = (corners_world - T_start[:3, 3]) @ T_start[:3, :3]
                for _ in range(int(round(HOLD_SECONDS / PYBULLET_DT))):
                    p.stepSimulation(physicsClientId=client)
                    # refresh the AABB each state only: the part is set, not moved, between states
                position_mm, angle_deg = _move(T_start, _link_pose(p, body, index, client), corners_link)
                drifts.append(Drift("pybullet (twin.urdf)", name, float(state), position_mm, angle_deg))
                lo, hi = (np.array(v) for v in p.getAABB(body, index, physicsClientId=client))
        base_end = p.getBasePositionAndOrientation(body, physicsClientId=client)
        fall_mm = float(np.linalg.norm(np.subtract(base_end[0], base_start[0])) * 1e3)
        drifts.append(Drift("pybullet (twin.urdf)", "base", 0.0, fall_mm, 0.0))
        return drifts
    finally:
        p.disconnect(client)


def _link_pose(p, body: int, index: int, client: int) -> np.ndarray:  # noqa: ANN001 - the pybullet module
    state = p.getLinkState(body, index, computeForwardKinematics=True, physicsClientId=client)
    return _pose(np.array(state[4]), Rotation.from_quat(state[5]).as_matrix())


def usd_to_mjspec(path: Path):  # noqa: ANN201 - mujoco.MjSpec
    """The articulation of twin.usda as a MuJoCo model, read with pxr only: each part body at its
    xform with its MassAPI, each joint from its localPos0/localRot0, axis, limits, drive damping
    and funrec:jointFriction. Collision shapes are left out (the exports exclude part-static
    contacts anyway), so this checks what the USD says, with MuJoCo's integrator."""
    import mujoco
    from pxr import Usd, UsdGeom, UsdPhysics

    stage = Usd.Stage.Open(str(path))
    gravity = UsdPhysics.Scene.Get(stage, "/physicsScene")
    assert gravity and tuple(gravity.GetGravityDirectionAttr().Get()) == (0.0, 0.0, -1.0)
    from funrec.export.mjcf import FRICTION_SOLIMP

    spec = mujoco.MjSpec()
    spec.compiler.degree = False
    spec.option.gravity = [0.0, 0.0, -float(gravity.GetGravityMagnitudeAttr().Get())]
    for prim in stage.Traverse():
        if not (prim.IsA(UsdPhysics.RevoluteJoint) or prim.IsA(UsdPhysics.PrismaticJoint)):
            continue
        revolute = prim.IsA(UsdPhysics.RevoluteJoint)
        joint = UsdPhysics.RevoluteJoint(prim) if revolute else UsdPhysics.PrismaticJoint(prim)
        assert joint.GetAxisAttr().Get() == "Z"
        body_prim = stage.GetPrimAtPath(joint.GetBody1Rel().GetTargets()[0])
        pos0, rot0 = joint.GetLocalPos0Attr().Get(), joint.GetLocalRot0Attr().Get()
        quat_wxyz = [rot0.GetReal(), *rot0.GetImaginary()]
        mass = UsdPhysics.MassAPI(body_prim)
        principal = mass.GetPrincipalAxesAttr().Get()
        body = spec.worldbody.add_body(name=body_prim.GetName(), pos=list(pos0), quat=quat_wxyz)
        body.mass = float(mass.GetMassAttr().Get())
        body.ipos = list(mass.GetCenterOfMassAttr().Get())
        body.iquat = [principal.GetReal(), *principal.GetImaginary()]
        body.inertia = list(mass.GetDiagonalInertiaAttr().Get())
        drive = UsdPhysics.DriveAPI(prim, "angular" if revolute else "linear")
        unit = math.pi / 180.0 if revolute else 1.0
        lower, upper = joint.GetLowerLimitAttr().Get() * unit, joint.GetUpperLimitAttr().Get() * unit
        mj_joint = body.add_joint(
            name=prim.GetName(),
            type=mujoco.mjtJoint.mjJNT_HINGE if revolute else mujoco.mjtJoint.mjJNT_SLIDE,
            axis=[0.0, 0.0, 1.0],
            range=[lower, upper],
            limited=mujoco.mjtLimited.mjLIMITED_TRUE,
            damping=float(drive.GetDampingAttr().Get()) / unit,
            frictionloss=float(prim.GetAttribute("funrec:jointFriction").Get()),
            armature=0.01,
            solimp_friction=[float(v) for v in FRICTION_SOLIMP.split()],
        )
        assert mj_joint is not None
        # The visual mesh's extent as a massless box: what the drift is measured on.
        lo, hi = (np.array(v) for v in UsdGeom.Mesh(body_prim.GetChild("visual")).GetExtentAttr().Get())
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=list((hi - lo) / 2.0), pos=list((hi + lo) / 2.0),
                      contype=0, conaffinity=0, density=0)
    return spec.compile()


def hold_usd(path: Path) -> list[Drift]:
    return hold_mujoco(usd_to_mjspec(path), "mujoco (twin.usda)")


def hold_all(twin_dir: Path) -> list[Drift]:
    """Every simulator on every part of a twin folder."""
    return [*hold_urdf(twin_dir / "twin.urdf"), *hold_mjcf(twin_dir / "twin.xml"), *hold_usd(twin_dir / "twin.usda")]


def main(argv: list[str]) -> int:
    for twin in argv:
        for d in hold_all(Path(twin)):
            print(f"{twin} {d.simulator:22s} {d.part:8s} state {d.state:+.3f}: {d.position_mm:.4f} mm {d.angle_deg:.5f} deg")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
