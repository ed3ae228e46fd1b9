"""Human-readable text about a robot: a one-line summary and a joint table with limits."""

from __future__ import annotations

import numpy as np

from funrec_robot.robot import RobotDescription


def robot_summary(robot: RobotDescription) -> str:
    """One line: name, planning DoF split into base and arm, base type, gripper DoF."""
    return (
        f"{robot.name}: {robot.nq} DoF ({len(robot.base_joints)} base, {len(robot.arm_joints)} arm), "
        f"base {robot.base_type}{' (differential drive)' if robot.drive == 'differential' else ''}, gripper {len(robot.gripper.joints)} finger joints"
    )


def _cell(value: float) -> str:
    return "-" if not np.isfinite(value) else f"{value:.4g}"


def format_robot(robot: RobotDescription) -> str:
    """A multi-line description: files, joint table (position, speed, acceleration, effort limits,
    home), end effector and grasp frame, gripper, held joints and simulation servos."""
    lines = [
        robot_summary(robot),
        f"  yaml:  {robot.yaml_path}",
        f"  model: {robot.model_path} (root body '{robot.root_body}')",
    ]
    if robot.urdf_path is not None:
        lines.append(f"  urdf:  {robot.urdf_path}")
    header = ("joint", "group", "lower", "upper", "v_max", "a_max", "effort", "home")
    rows = []
    for i, name in enumerate(robot.joint_names):
        group = f"base {robot.base_motions[i]}" if i < len(robot.base_joints) else "arm"
        values = (robot.q_min[i], robot.q_max[i], robot.v_max[i], robot.a_max[i], robot.effort_max[i], robot.q_home[i])
        rows.append((name, group, *(_cell(v) for v in values)))
    widths = [max(len(row[c]) for row in (header, *rows)) for c in range(len(header))]
    lines.append("  units: m, rad, /s, /s^2, N, N m; '-' is unlimited")
    for row in (header, *rows):
        lines.append("  " + "  ".join(text.ljust(width) for text, width in zip(row, widths)).rstrip())
    lines.append(
        f"  end effector: site '{robot.ee_site}'; grasp frame site '{robot.grasp_site}' (z approach, y finger axis)"
    )
    if robot.grasp_site != robot.ee_site:
        for row in np.round(robot.T_ee_grasp, 6):
            lines.append("    T_ee_grasp " + " ".join(f"{v + 0.0: .4g}" for v in row))
    gripper = robot.gripper
    driver = f"actuator '{gripper.actuator}'" if gripper.actuator else "servos on the finger joints"
    lines.append(
        f"  gripper: joints {', '.join(gripper.joints)}; {driver}; open {gripper.open:g}, closed {gripper.closed:g}"
    )
    if robot.held_joints:
        held = ", ".join(f"{name} at {value:g}" for name, value in robot.held_joints.items())
        lines.append(f"  held joints: {held}")
    if robot.servos:
        servos = ", ".join(f"{name} (kp {g.kp:g}, kv {g.kv:g}, max {g.force:g})" for name, g in robot.servos.items())
        lines.append(f"  servos added in simulation: {servos}")
    lines.append(f"  gravity compensation in simulation: {'on' if robot.gravity_compensation else 'off'}")
    return "\n".join(lines)


__all__ = ["format_robot", "robot_summary"]
