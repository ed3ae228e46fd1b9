"""funrec_robot: mobile manipulators that replay the interactions FunREC reconstructs.

Names are imported on first use, so ``funrec-robot --help`` does not load MuJoCo and the CLI can
choose the OpenGL backend (MUJOCO_GL) before MuJoCo is imported.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from funrec_robot.catalog import DEFAULT_ROBOT, default_robot_path, find_robots, resolve_robot
    from funrec_robot.errors import RobotDescriptionError, UnknownNameError
    from funrec_robot.robot import GripperDescription, RobotDescription, ServoGains, load_robot
    from funrec_robot.sim_model import (
        ROBOT_PREFIX,
        RobotIndices,
        build_mujoco_model,
        build_mujoco_spec,
        reset_to_home,
        robot_indices,
    )

_MODULE_OF = {
    "DEFAULT_ROBOT": "catalog",
    "default_robot_path": "catalog",
    "find_robots": "catalog",
    "resolve_robot": "catalog",
    "RobotDescriptionError": "errors",
    "UnknownNameError": "errors",
    "GripperDescription": "robot",
    "RobotDescription": "robot",
    "ServoGains": "robot",
    "load_robot": "robot",
    "ROBOT_PREFIX": "sim_model",
    "RobotIndices": "sim_model",
    "build_mujoco_model": "sim_model",
    "build_mujoco_spec": "sim_model",
    "reset_to_home": "sim_model",
    "robot_indices": "sim_model",
}


def __getattr__(name: str) -> Any:
    if name not in _MODULE_OF:
        raise AttributeError(f"module 'funrec_robot' has no attribute '{name}'")
    return getattr(importlib.import_module(f"funrec_robot.{_MODULE_OF[name]}"), name)


__all__ = [
    "DEFAULT_ROBOT",
    "ROBOT_PREFIX",
    "GripperDescription",
    "RobotDescription",
    "RobotDescriptionError",
    "RobotIndices",
    "ServoGains",
    "UnknownNameError",
    "build_mujoco_model",
    "build_mujoco_spec",
    "default_robot_path",
    "find_robots",
    "load_robot",
    "reset_to_home",
    "resolve_robot",
    "robot_indices",
]
