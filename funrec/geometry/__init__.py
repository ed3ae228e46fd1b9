"""Pure geometry on numpy arrays: rigid transforms, pinhole cameras, joint transforms.

Nothing here does I/O, logging or reads configuration.
"""

from funrec.geometry.camera import PinholeIntrinsics, backproject, project
from funrec.geometry.joints import (
    JOINT_TYPES,
    closest_point_on_axis_to_origin,
    joint_transform,
    joint_transforms,
)
from funrec.geometry.transforms import (
    check_transform,
    invert_transform,
    make_transform,
    rotation_about_axis,
    transform_points,
)

__all__ = [
    "JOINT_TYPES",
    "PinholeIntrinsics",
    "backproject",
    "check_transform",
    "closest_point_on_axis_to_origin",
    "invert_transform",
    "joint_transform",
    "joint_transforms",
    "make_transform",
    "project",
    "rotation_about_axis",
    "transform_points",
]
