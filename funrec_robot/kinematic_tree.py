"""One Python description of a robot's links, joints, geometry and servos, written out as MJCF and URDF.

``model_writer.py`` turns a :class:`KinematicTree` into both files, so the two can never disagree.
Every frame here is a link frame at zero joint positions; rotations are URDF roll-pitch-yaw
(extrinsic x, then y, then z: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

Vec3 = tuple[float, float, float]

JointKind = Literal["revolute", "prismatic"]
GeomKind = Literal["box", "capsule", "cylinder", "sphere"]

_GEOM_SIZE_COUNT: dict[str, int] = {"box": 3, "capsule": 2, "cylinder": 2, "sphere": 1}
_UNIT_AXIS_TOL = 1e-9
"""Joint axes are written exactly; anything further from unit length is a typo."""


@dataclass(frozen=True)
class Joint:
    """A one-degree-of-freedom joint at the origin of its child link frame."""

    name: str
    """Joint name, the same in the MJCF and the URDF."""
    kind: JointKind
    """``revolute`` (MJCF hinge) or ``prismatic`` (MJCF slide)."""
    axis: Vec3
    """(3,) unit axis in the child link frame."""
    lower: float
    """Lower position limit, rad or m."""
    upper: float
    """Upper position limit, rad or m."""
    velocity: float
    """Speed limit, rad/s or m/s."""
    acceleration: float
    """Acceleration limit, rad/s^2 or m/s^2 (URDF and MJCF have no field for it; it goes to the robot YAML)."""
    effort: float
    """Actuator torque or force limit, N m or N (URDF ``effort``, MJCF ``actuatorfrcrange``)."""
    damping: float = 0.0
    """Viscous friction, N m s/rad or N s/m."""
    armature: float = 0.0
    """Reflected rotor inertia, kg m^2 or kg (MJCF only; pinocchio's URDF parser has no field for it)."""

    def __post_init__(self) -> None:
        if abs(math.sqrt(sum(a * a for a in self.axis)) - 1.0) > _UNIT_AXIS_TOL:
            raise ValueError(f"joint '{self.name}': axis {self.axis} is not a unit vector")
        if not self.lower < self.upper:
            raise ValueError(f"joint '{self.name}': lower {self.lower} must be below upper {self.upper}")
        if min(self.velocity, self.acceleration, self.effort) <= 0.0:
            raise ValueError(f"joint '{self.name}': velocity, acceleration and effort limits must be positive")


@dataclass(frozen=True)
class Geom:
    """A primitive shape attached to a link, for collision and display."""

    kind: GeomKind
    """Shape type; capsules become a cylinder and two spheres in the URDF (the same solid)."""
    size: tuple[float, ...]
    """Box: (3,) half extents, m. Capsule and cylinder: (radius, half length along local z), m. Sphere: (radius,)."""
    pos: Vec3 = (0.0, 0.0, 0.0)
    """(3,) centre in the link frame, m."""
    rpy: Vec3 = (0.0, 0.0, 0.0)
    """Orientation in the link frame, rad (roll, pitch, yaw)."""
    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)
    """Display colour."""
    collision: bool = True
    """False for display-only shapes (MJCF contype=conaffinity=0; URDF visual only)."""

    def __post_init__(self) -> None:
        if len(self.size) != _GEOM_SIZE_COUNT[self.kind] or min(self.size) <= 0.0:
            raise ValueError(f"{self.kind} geom: size {self.size} needs {_GEOM_SIZE_COUNT[self.kind]} positive values")


@dataclass(frozen=True)
class Inertial:
    """Mass properties of a link with principal axes along the link frame axes."""

    mass: float
    """Mass, kg."""
    com: Vec3
    """(3,) centre of mass in the link frame, m."""
    inertia: Vec3
    """(3,) principal moments (ixx, iyy, izz) about the centre of mass, kg m^2."""

    @classmethod
    def solid_cylinder(cls, mass: float, radius: float, length: float, com: Vec3) -> Inertial:
        """Inertia of a solid cylinder along the link z axis.

        Args:
            mass: kg.
            radius: m.
            length: m, along z.
            com: (3,) centre of the cylinder in the link frame, m.
        """
        transverse = mass * (3.0 * radius**2 + length**2) / 12.0
        return cls(mass, com, (transverse, transverse, 0.5 * mass * radius**2))

    @classmethod
    def solid_box(cls, mass: float, half_extents: Vec3, com: Vec3) -> Inertial:
        """Inertia of a solid box with the given (3,) half extents in m, centred at ``com``."""
        x, y, z = (2.0 * h for h in half_extents)
        return cls(
            mass, com, (mass * (y * y + z * z) / 12.0, mass * (x * x + z * z) / 12.0, mass * (x * x + y * y) / 12.0)
        )


@dataclass(frozen=True)
class Site:
    """A named frame on a link (MJCF site; URDF massless link on a fixed joint)."""

    name: str
    """Site name, the same in both files."""
    pos: Vec3 = (0.0, 0.0, 0.0)
    """(3,) origin in the link frame, m."""
    rpy: Vec3 = (0.0, 0.0, 0.0)
    """Orientation in the link frame, rad."""


@dataclass(frozen=True)
class Link:
    """A rigid body; its frame sits at ``pos``/``rpy`` in the parent link frame when its joints are zero."""

    name: str
    """Link (MJCF body) name."""
    parent: str | None
    """Parent link name; None for the root, which is placed in the world frame."""
    pos: Vec3 = (0.0, 0.0, 0.0)
    """(3,) origin in the parent link frame, m."""
    rpy: Vec3 = (0.0, 0.0, 0.0)
    """Orientation in the parent link frame, rad."""
    joints: tuple[Joint, ...] = ()
    """Joints applied in order at the link origin: none welds the link to its parent, several make a
    chain (MJCF: one body with several joints; URDF: massless intermediate links)."""
    inertial: Inertial | None = None
    """Mass properties; None for a massless frame link."""
    geoms: tuple[Geom, ...] = ()
    """Shapes in the link frame."""
    sites: tuple[Site, ...] = ()
    """Named frames in the link frame."""


@dataclass(frozen=True)
class PositionServo:
    """A MuJoCo position actuator ``force = kp (ctrl - q) - kv qdot``, clamped to the joint effort."""

    name: str
    """Actuator name."""
    joint: str
    """Driven joint; the control range is the joint's position range."""
    kp: float
    """Position gain, N m/rad or N/m."""
    kv: float
    """Velocity gain, N m s/rad or N s/m."""


@dataclass(frozen=True)
class JointCoupling:
    """``follower = ratio * leader`` (MJCF joint equality; URDF ``mimic``)."""

    follower: str
    """Joint that follows."""
    leader: str
    """Joint that leads."""
    ratio: float = 1.0
    """Multiplier."""


@dataclass(frozen=True)
class KinematicTree:
    """A whole robot: links in parent-before-child order, servos and joint couplings."""

    name: str
    """Model name."""
    links: tuple[Link, ...]
    """Links; the first is the root, every parent appears before its children."""
    servos: tuple[PositionServo, ...] = ()
    """Position actuators of the MJCF."""
    couplings: tuple[JointCoupling, ...] = ()
    """Joint couplings (gripper fingers)."""
    excluded_contacts: tuple[tuple[str, str], ...] = ()
    """Link pairs whose contacts MuJoCo ignores (parent-child pairs are ignored anyway)."""
    timestep: float = 0.002
    """MuJoCo integration step, s."""
    _joints: dict[str, Joint] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        seen: set[str] = set()
        for index, link in enumerate(self.links):
            if link.name in seen:
                raise ValueError(f"link '{link.name}' appears twice")
            if (link.parent is None) != (index == 0):
                raise ValueError(f"link '{link.name}': only the first link is the root")
            if link.parent is not None and link.parent not in seen:
                raise ValueError(f"link '{link.name}': parent '{link.parent}' must come before it")
            if link.inertial is None and (link.geoms or link.joints):
                # MuJoCo would infer a mass from the geoms that the URDF does not have.
                raise ValueError(f"link '{link.name}': a link with geoms or joints needs an Inertial")
            seen.add(link.name)
        joints = {joint.name: joint for link in self.links for joint in link.joints}
        object.__setattr__(self, "_joints", joints)
        for servo in self.servos:
            if servo.joint not in joints:
                raise ValueError(f"servo '{servo.name}': unknown joint '{servo.joint}'")
        for coupling in self.couplings:
            if coupling.follower not in joints or coupling.leader not in joints:
                raise ValueError(f"coupling {coupling}: unknown joint")

    def joint(self, name: str) -> Joint:
        """The joint called ``name``."""
        return self._joints[name]

    @property
    def joint_names(self) -> tuple[str, ...]:
        """All joint names in tree order."""
        return tuple(self._joints)


__all__ = ["Geom", "Inertial", "Joint", "JointCoupling", "KinematicTree", "Link", "PositionServo", "Site"]
