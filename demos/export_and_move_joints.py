"""Load a twin's simulator exports and move each joint through its range: twin.xml in MuJoCo and twin.urdf
with yourdfpy, printing where each part's body is at the lower and upper limit in both.

    python demos/export_and_move_joints.py --twin TWIN      # a twin folder from funrec reconstruct
    python demos/export_and_move_joints.py -o demo_output   # or generate a capture and reconstruct it first
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import yourdfpy
from reconstruct_and_view import twin_from, twin_parser  # the sibling demo (python puts demos/ on the path)


def mujoco_positions(xml: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per joint: world position of its body's centre of mass at the lower and the upper limit (MuJoCo)."""
    model = mujoco.MjModel.from_xml_path(str(xml))
    data = mujoco.MjData(model)
    out = {}
    for j in range(model.njnt):
        if int(model.jnt_type[j]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            continue
        ends = []
        for q in model.jnt_range[j]:
            data.qpos[:] = model.qpos0
            data.qpos[model.jnt_qposadr[j]] = q
            mujoco.mj_kinematics(model, data)
            ends.append(data.xipos[model.jnt_bodyid[j]].copy())
        out[model.joint(j).name] = (ends[0], ends[1])
    return out


def urdf_positions(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The same with the URDF: each joint's child link's centre of mass in the base link's frame."""
    urdf = yourdfpy.URDF.load(str(path))
    out = {}
    for name in urdf.actuated_joint_names:
        joint = urdf.joint_map[name]
        inertial = urdf.link_map[joint.child].inertial
        p_link = np.append(inertial.origin[:3, 3] if inertial is not None and inertial.origin is not None else np.zeros(3), 1.0)
        ends = []
        for q in (joint.limit.lower, joint.limit.upper):
            urdf.update_cfg({name: q})
            ends.append((urdf.get_transform(joint.child, urdf.base_link) @ p_link)[:3])
        urdf.update_cfg({name: 0.0})
        out[name] = (ends[0], ends[1])
    return out


def main() -> None:
    twin = twin_from(twin_parser(__doc__).parse_args())
    in_mujoco, in_urdf = mujoco_positions(twin / "twin.xml"), urdf_positions(twin / "twin.urdf")
    print(f"{len(in_mujoco)} joint(s) in twin.xml, {len(in_urdf)} in twin.urdf")
    for name, (low, high) in in_mujoco.items():
        print(f"{name}: MuJoCo body at lower limit {low.round(3)}, upper {high.round(3)}, moved {np.linalg.norm(high - low):.4f} m")
    for name, (low, high) in in_urdf.items():
        print(f"{name}: URDF link at lower limit {low.round(3)}, upper {high.round(3)}, moved {np.linalg.norm(high - low):.4f} m")


if __name__ == "__main__":
    main()
