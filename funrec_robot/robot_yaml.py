"""Read a robot YAML file into plain typed values, rejecting unknown keys and wrong types.

Only the file's own structure is checked here; ``robot.py`` checks the names and numbers against
the model. Every error names the file and the key path (``gripper.open: expected a number``).
"""

from __future__ import annotations

import importlib.util
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from funrec_robot.errors import RobotDescriptionError, format_names

PACKAGE_SCHEME = "package://"
"""Prefix of a model path inside an installed Python package: ``package://<import name>/<path>``."""

BASE_MOTIONS = ("x", "y", "yaw")
"""Motions a mobile base can have, in the order their joints must appear in the model."""

MODELS_SCHEME = "models://"
"""Prefix of a model path inside the robot models folder: ``models://<path>``, relative to the folder named by
the environment variable ``FUNREC_ROBOT_MODELS`` (``funrec-robot --models DIR`` sets it)."""

MODELS_ENV = "FUNREC_ROBOT_MODELS"
"""Environment variable naming the robot models folder."""

PLANAR_JOINTS = {"x": "base_x", "y": "base_y", "yaw": "base_yaw"}
"""Joints funrec_robot adds to the root body in place of its free joint for ``base: {planar: true}``."""

BASE_LIFT_JOINT = "base_lift"
"""Vertical slide funrec_robot adds to the root body after ``PLANAR_JOINTS`` for ``base: {planar: true, lift: true}``
(a legged body that crouches or rises): the file lists it first in ``arm_joints``, so the planner treats it as a
lift (``reach.lifted``) and the whole-body IK moves it with the arm."""

BASE_PITCH_JOINT = "base_pitch"
"""Hinge about the root body's y axis, through its origin, that funrec_robot adds after ``PLANAR_JOINTS`` (and
``BASE_LIFT_JOINT``) for ``base: {planar: true, pitch: true}`` (a legged body that pitches nose down or up; positive
is nose down for a body whose x points forward): the file lists it in ``arm_joints`` and the whole-body IK moves it
with the arm."""

DRIVES = ("holonomic", "differential")
"""How a base moves: 'holonomic' (any planar motion), 'differential' (wheels: only along its heading, and
turning on the spot)."""

EE_SITE_SUFFIX = "_funrec_ee"
"""Name suffix of the end-effector site funrec_robot adds to ``ee.body`` (models without sites)."""


@dataclass(frozen=True)
class ServoEntry:
    """Gains of a position servo that funrec_robot adds for a joint without an actuator."""

    kp: float
    """Position gain, N m/rad or N/m."""
    kv: float
    """Velocity gain, N m s/rad or N s/m."""


@dataclass(frozen=True)
class RobotFile:
    """The contents of a robot YAML file, structure-checked but not yet checked against the model."""

    path: Path
    """The YAML file."""
    name: str
    """Robot name (default: the file stem)."""
    model: Path
    """Resolved MJCF or URDF path."""
    urdf: Path | None
    """Resolved URDF path of the same robot, for pinocchio, or None."""
    root_body: str | None
    """Body whose subtree is the robot; None: the model's only top-level body."""
    base: dict[str, str]
    """Motion ('x', 'y', 'yaw') -> joint name."""
    arm_joints: tuple[str, ...]
    """Arm joint names, from the base to the hand."""
    gripper_joints: tuple[str, ...]
    """Finger joint names."""
    gripper_actuator: str | None
    """Actuator that drives the fingers, or None (servos are added on the finger joints)."""
    gripper_open: float
    """Gripper command when open: actuator control, or finger joint position, m or rad."""
    gripper_closed: float
    """Gripper command when closed, same unit."""
    ee_site: str
    """End-effector site name."""
    approach_axis: tuple[float, float, float]
    """(3,) grasp z axis in the site frame."""
    closing_axis: tuple[float, float, float]
    """(3,) grasp y axis in the site frame."""
    offset: tuple[float, float, float]
    """(3,) grasp origin in the site frame, m."""
    held_joints: dict[str, float]
    """Joint -> position the simulation holds it at (joints the planner never moves)."""
    home: dict[str, float]
    """Planning joint -> home position."""
    position_limits: dict[str, tuple[float, float]]
    """Joint -> (lower, upper) override."""
    velocity_limits: dict[str, float]
    """Joint -> speed limit, rad/s or m/s."""
    acceleration_limits: dict[str, float]
    """Joint -> acceleration limit, rad/s^2 or m/s^2."""
    effort_limits: dict[str, float]
    """Joint -> torque or force limit, N m or N."""
    gravity_compensation: bool
    """Whether the simulated controllers cancel gravity."""
    damping: dict[str, float]
    """Joint -> viscous damping that replaces the model's in simulation."""
    servos: dict[str, ServoEntry]
    """Joint -> gains of the servo added to it."""
    postures: tuple[dict[str, float], ...] = ()
    """Other home postures (planning joint -> position, the rest as in ``home``), tried in order when the arm
    in the first cannot hold the gripper within its effort limits."""
    planar_base: bool = False
    """The root body's free joint is replaced by ``PLANAR_JOINTS`` (a kinematic planar base: legged bodies,
    wheeled bases whose wheels the model simulates with contacts)."""
    drive: str = "holonomic"
    """One of ``DRIVES``."""
    base_height: float = 0.0
    """Height of the root body's frame above the floor with a planar base, m (a legged body standing)."""
    base_lift: bool = False
    """A planar base whose body also moves up and down on ``BASE_LIFT_JOINT``."""
    base_pitch: bool = False
    """A planar base whose body also pitches on ``BASE_PITCH_JOINT``."""
    ee_body: str | None = None
    """Body the end-effector site ``ee_site`` is added to (at its origin), for models without a site."""
    gripper_extra_actuators: tuple[str, ...] = ()
    """Further actuators that get the same command as ``gripper_actuator`` (one per finger)."""
    gripper_open_width: float | None = None
    """Gap between the jaws at the open command, m (None: twice the command span, for finger slides)."""
    gripper_release_gap: float | None = None
    """How far each finger opens clear of the handle on letting go, m (None: the planner's default)."""
    gripper_release_sweep: float | None = None
    """How much deeper into the part or the scene the opening gripper may go on letting go than while holding, m
    (None: not checked)."""
    gripper_release_time: float | None = None
    """How long the gripper takes to open on letting go, s (None: the planner's default)."""
    gripper_fall_rest_force: float | None = None
    """Most weight a part let go to fall may rest on a finger with, N (None: the planner's default)."""
    gripper_fall_retreat_scale: float | None = None
    """Speed of the retreat from a part let go to fall, as a fraction of the usual (None: the planner's default)."""
    masses: dict[str, float] = field(default_factory=dict)
    """Body -> mass replacing the model's, kg (its inertia scaled alike), for a model file whose masses are wrong."""
    coupled_joints: dict[str, tuple[str, float]] = field(default_factory=dict)
    """Follower joint -> (leader joint, ratio): the follower's position is ``ratio`` times the leader's (a
    telescoping arm's stages, fingers geared to one slide); the model's joint equalities (or ones added in
    simulation) keep them so."""
    drop_actuators: tuple[str, ...] = ()
    """Actuators of the model left out of every model built for the robot (one replaced by a servo the file adds,
    e.g. a tendon actuator of coupled joints whose leader gets a joint servo instead)."""


class _Reader:
    """Typed access to nested YAML values; errors quote the file and the key path."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, key: str, problem: str) -> RobotDescriptionError:
        return RobotDescriptionError(self.path, f"{key}: {problem}")

    def mapping(self, value: Any, key: str, allowed: tuple[str, ...] | None = None) -> dict[str, Any]:
        if value is None:
            return {}
        if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
            raise self.fail(key, f"expected a mapping with text keys, got {type(value).__name__}")
        if allowed is not None:
            unknown = sorted(set(value) - set(allowed))
            if unknown:
                raise self.fail(key, f"unknown key {format_names(unknown)}; valid keys: {format_names(allowed)}")
        return value

    def text(self, value: Any, key: str) -> str:
        if not isinstance(value, str) or not value:
            raise self.fail(key, f"expected a name, got {value!r}")
        return value

    def number(self, value: Any, key: str, minimum: float | None = None, positive: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.fail(key, f"expected a finite number, got {value!r}")
        if minimum is not None and value < minimum:
            raise self.fail(key, f"must be at least {minimum:g}, got {value!r}")
        if positive and value <= 0:
            raise self.fail(key, f"must be positive, got {value!r}")
        return float(value)

    def names(self, value: Any, key: str) -> tuple[str, ...]:
        if not isinstance(value, list):
            raise self.fail(key, f"expected a list of names, got {value!r}")
        names = tuple(self.text(item, f"{key}[{i}]") for i, item in enumerate(value))
        if len(set(names)) != len(names):
            raise self.fail(key, f"names repeat: {list(names)}")
        return names

    def vector3(self, value: Any, key: str) -> tuple[float, float, float]:
        if not isinstance(value, list) or len(value) != 3:
            raise self.fail(key, f"expected 3 numbers, got {value!r}")
        x, y, z = (self.number(v, key) for v in value)
        return (x, y, z)

    def number_map(
        self, value: Any, key: str, minimum: float | None = None, positive: bool = False
    ) -> dict[str, float]:
        items = self.mapping(value, key)
        return {name: self.number(v, f"{key}.{name}", minimum, positive) for name, v in items.items()}

    def path_of(self, value: Any, key: str) -> Path:
        text = self.text(value, key)
        if text.startswith(MODELS_SCHEME):
            folder = os.environ.get(MODELS_ENV)
            if not folder:
                raise self.fail(key, f"'{text}': set {MODELS_ENV} (or pass --models DIR) to the robot models folder")
            path = Path(folder) / text[len(MODELS_SCHEME) :]
            if not path.is_file():
                raise self.fail(key, f"'{text}': no such file {path} ({MODELS_ENV}={folder})")
            return path.resolve()
        if text.startswith(PACKAGE_SCHEME):
            package, _, inner = text[len(PACKAGE_SCHEME) :].partition("/")
            spec = importlib.util.find_spec(package) if package.isidentifier() else None
            if spec is None or not spec.submodule_search_locations:
                raise self.fail(key, f"'{text}': Python package '{package}' is not installed")
            path = Path(next(iter(spec.submodule_search_locations))) / inner
        else:
            path = self.path.parent / text
        if not path.is_file():
            raise self.fail(key, f"'{text}': no such file {path}")
        return path.resolve()


_TOP_KEYS = (
    "name", "model", "urdf", "root_body", "base", "arm_joints", "gripper", "ee",
    "held_joints", "coupled_joints", "home", "postures", "limits", "simulation",
)  # fmt: skip
_REQUIRED = ("model", "arm_joints", "gripper", "ee")


def read_robot_yaml(path: str | Path) -> RobotFile:
    """Parse and structure-check a robot YAML file.

    Args:
        path: the YAML file.

    Returns:
        Its contents with paths resolved (relative to the file, or ``package://`` in an installed package).

    Raises:
        RobotDescriptionError: unreadable file, unknown key, missing key, wrong type or missing model file.
    """
    path = Path(path)
    if not path.is_file():
        raise RobotDescriptionError(path, "no such robot YAML file")
    try:
        document = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise RobotDescriptionError(path, f"not valid YAML: {exc}") from exc
    r = _Reader(path)
    top = r.mapping(document, "(top level)", _TOP_KEYS)
    missing = [key for key in _REQUIRED if key not in top]
    if missing:
        raise r.fail("(top level)", f"missing key {format_names(missing)}")
    base = r.mapping(top.get("base"), "base", (*BASE_MOTIONS, "planar", "drive", "height", "lift", "pitch"))
    planar = base.get("planar", False)
    if not isinstance(planar, bool):
        raise r.fail("base.planar", f"expected true or false, got {planar!r}")
    drive = base.get("drive", "holonomic")
    if drive not in DRIVES:
        raise r.fail("base.drive", f"expected one of {format_names(DRIVES)}, got {drive!r}")
    motions = {m: r.text(base[m], f"base.{m}") for m in BASE_MOTIONS if m in base}
    if planar and motions:
        raise r.fail("base", f"planar: true adds the base joints {format_names(PLANAR_JOINTS.values())}; do not name x, y or yaw as well")
    if planar:
        motions = dict(PLANAR_JOINTS)
    lift, pitch = (_body_motion(r, base, key, planar) for key in ("lift", "pitch"))
    gripper = r.mapping(top["gripper"], "gripper", ("joints", "actuator", "open", "closed", "open_width", "release_gap", "release_sweep",
                                                        "release_time", "fall_rest_force", "fall_retreat_scale"))
    for key in ("joints", "open", "closed"):
        if key not in gripper:
            raise r.fail("gripper", f"missing key '{key}'")
    ee = r.mapping(top["ee"], "ee", ("site", "body", "approach_axis", "closing_axis", "offset"))
    if ("site" in ee) == ("body" in ee):
        raise r.fail("ee", "expected exactly one of 'site' (a site of the model) or 'body' (a site is added at its origin)")
    ee_body = r.text(ee["body"], "ee.body") if "body" in ee else None
    actuators = gripper.get("actuator")
    actuators = r.names(actuators, "gripper.actuator") if isinstance(actuators, list) else (
        (r.text(actuators, "gripper.actuator"),) if actuators is not None else ())
    limits = r.mapping(top.get("limits"), "limits", ("position", "velocity", "acceleration", "effort"))
    position = r.mapping(limits.get("position"), "limits.position")
    simulation = r.mapping(top.get("simulation"), "simulation", ("gravity_compensation", "damping", "servos", "masses", "drop_actuators"))
    gravity = simulation.get("gravity_compensation", False)
    if not isinstance(gravity, bool):
        raise r.fail("simulation.gravity_compensation", f"expected true or false, got {gravity!r}")
    servos = {}
    for joint, entry in r.mapping(simulation.get("servos"), "simulation.servos").items():
        key = f"simulation.servos.{joint}"
        gains = r.mapping(entry, key, ("kp", "kv"))
        if set(gains) != {"kp", "kv"}:
            raise r.fail(key, "expected both 'kp' and 'kv'")
        servos[joint] = ServoEntry(r.number(gains["kp"], f"{key}.kp", 0.0), r.number(gains["kv"], f"{key}.kv", 0.0))
    position_limits = {}
    for joint, bounds in position.items():
        key = f"limits.position.{joint}"
        if not isinstance(bounds, list) or len(bounds) != 2:
            raise r.fail(key, f"expected [lower, upper], got {bounds!r}")
        lower, upper = r.number(bounds[0], key), r.number(bounds[1], key)
        if not lower < upper:
            raise r.fail(key, f"lower {lower:g} must be below upper {upper:g}")
        position_limits[joint] = (lower, upper)
    return RobotFile(
        path=path,
        name=r.text(top.get("name", path.stem), "name"),
        model=r.path_of(top["model"], "model"),
        urdf=r.path_of(top["urdf"], "urdf") if "urdf" in top else None,
        root_body=r.text(top["root_body"], "root_body") if "root_body" in top else None,
        base=motions,
        arm_joints=r.names(top["arm_joints"], "arm_joints"),
        gripper_joints=r.names(gripper["joints"], "gripper.joints"),
        gripper_actuator=actuators[0] if actuators else None,
        gripper_open=r.number(gripper["open"], "gripper.open"),
        gripper_closed=r.number(gripper["closed"], "gripper.closed"),
        ee_site=r.text(ee["site"], "ee.site") if ee_body is None else ee_body + EE_SITE_SUFFIX,
        approach_axis=r.vector3(ee.get("approach_axis", [0, 0, 1]), "ee.approach_axis"),
        closing_axis=r.vector3(ee.get("closing_axis", [0, 1, 0]), "ee.closing_axis"),
        offset=r.vector3(ee.get("offset", [0, 0, 0]), "ee.offset"),
        held_joints=r.number_map(top.get("held_joints"), "held_joints"),
        home=r.number_map(top.get("home"), "home"),
        position_limits=position_limits,
        velocity_limits=r.number_map(limits.get("velocity"), "limits.velocity", positive=True),
        acceleration_limits=r.number_map(limits.get("acceleration"), "limits.acceleration", positive=True),
        effort_limits=r.number_map(limits.get("effort"), "limits.effort", positive=True),
        gravity_compensation=gravity,
        damping=r.number_map(simulation.get("damping"), "simulation.damping", 0.0),
        servos=servos,
        postures=_postures(r, top.get("postures")),
        planar_base=planar,
        drive=drive,
        base_height=r.number(base.get("height", 0.0), "base.height", 0.0),
        base_lift=lift,
        base_pitch=pitch,
        ee_body=ee_body,
        gripper_extra_actuators=actuators[1:],
        masses=r.number_map(simulation.get("masses"), "simulation.masses", positive=True),
        gripper_open_width=r.number(gripper["open_width"], "gripper.open_width", positive=True) if "open_width" in gripper else None,
        gripper_release_gap=r.number(gripper["release_gap"], "gripper.release_gap", positive=True) if "release_gap" in gripper else None,
        gripper_release_sweep=r.number(gripper["release_sweep"], "gripper.release_sweep", positive=True) if "release_sweep" in gripper else None,
        gripper_release_time=r.number(gripper["release_time"], "gripper.release_time", positive=True) if "release_time" in gripper else None,
        gripper_fall_rest_force=(r.number(gripper["fall_rest_force"], "gripper.fall_rest_force", positive=True)
                                 if "fall_rest_force" in gripper else None),
        gripper_fall_retreat_scale=(_fraction(r, gripper["fall_retreat_scale"], "gripper.fall_retreat_scale")
                                    if "fall_retreat_scale" in gripper else None),
        coupled_joints=_couplings(r, top.get("coupled_joints")),
        drop_actuators=r.names(simulation.get("drop_actuators", []), "simulation.drop_actuators"),
    )


def _body_motion(r: _Reader, base: dict, key: str, planar: bool) -> bool:
    """``base.lift`` / ``base.pitch``: true or false, true only with ``planar: true``."""
    value = base.get(key, False)
    if not isinstance(value, bool):
        raise r.fail(f"base.{key}", f"expected true or false, got {value!r}")
    if value and not planar:
        raise r.fail(f"base.{key}", f"a body {key} is added to a planar base only: set planar: true")
    return value


def _couplings(r: _Reader, value: object) -> dict[str, tuple[str, float]]:
    """``{follower: leader}`` or ``{follower: {joint: leader, ratio: r}}`` (ratio 1 by default)."""
    out = {}
    for follower, entry in r.mapping(value, "coupled_joints").items():
        key = f"coupled_joints.{follower}"
        if isinstance(entry, dict):
            entry = r.mapping(entry, key, ("joint", "ratio"))
            if "joint" not in entry:
                raise r.fail(key, "missing key 'joint' (the leading joint)")
            ratio = r.number(entry.get("ratio", 1.0), f"{key}.ratio")
            if ratio == 0.0:
                raise r.fail(f"{key}.ratio", "must not be zero")
            out[follower] = (r.text(entry["joint"], f"{key}.joint"), ratio)
        else:
            out[follower] = (r.text(entry, key), 1.0)
    return out


def _fraction(r: _Reader, value: object, key: str) -> float:
    """A number in (0, 1]."""
    number = r.number(value, key, positive=True)
    if number > 1.0:
        raise r.fail(key, f"expected a fraction in (0, 1], got {value!r}")
    return number


def _postures(r: _Reader, value: object) -> tuple[dict[str, float], ...]:
    if value is None:
        return ()
    if not isinstance(value, list):
        raise r.fail("postures", f"expected a list of {{joint: position}} maps, got {value!r}")
    return tuple(r.number_map(entry, f"postures[{k}]") for k, entry in enumerate(value))


__all__ = [
    "BASE_LIFT_JOINT", "BASE_MOTIONS", "BASE_PITCH_JOINT", "DRIVES", "EE_SITE_SUFFIX", "MODELS_ENV", "MODELS_SCHEME", "PACKAGE_SCHEME", "PLANAR_JOINTS", "RobotFile",
    "ServoEntry", "read_robot_yaml",
]
