"""The signed check record of a plan: what ``funrec-robot check`` attests, bound to the exact bytes of the
plan, the robot file and the scene it judged, and signed with the checking user's Ed25519 key.

``PLAN.check.json`` (``"format": "funrec-check/2"``) holds ``attested`` (the signed facts: plan sha256,
robot file and its sha256, scene file and the sha256 of its folder, every criterion with its threshold and
measured value, all check settings, the FunREC version and the time), ``signature`` (ed25519 over the
canonical JSON of ``attested``) and ``report`` (the full report, informational, not signed). Senders and
endpoints accept a plan only through :func:`verify_check_record`, which refuses unsigned, forged, untrusted,
failed, other-plan and loosened records, each with its reason.
"""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from funrec.errors import FormatError, PlanningError
from funrec.formats.staged_folder import write_text_staged
from funrec.formats.twin import read_json_object
from funrec_robot.check import CheckConfig, CheckReport
from funrec_robot.keys import SigningKey, TrustError, load_signing_key, sign, trusted_keys, verify
from funrec_robot.plan_file import sha256_file

CHECK_FORMAT = "funrec-check/2"
"""Format tag written into and required from a check record (funrec-check/1 records were unsigned)."""

POLICY_FIELDS = (
    "revolute_tolerance",
    "prismatic_tolerance",
    "max_handle_force",
    "position_tolerance",
    "velocity_tolerance",
    "effort_time",
    "engage_distance",
    "handle_radius",
    "contact_radius",
)
"""Check settings where a larger value is a looser check; an endpoint refuses values above its policy's."""


@dataclass(frozen=True)
class CheckPolicy:
    """The loosest check an endpoint accepts: every ``POLICY_FIELDS`` setting at most the policy's (default:
    ``CheckConfig``'s defaults, i.e. exactly what `funrec-robot check` judges with no options)."""

    limits: tuple[tuple[str, float], ...] = tuple(
        (name, float(getattr(CheckConfig(), name))) for name in POLICY_FIELDS
    )
    """(setting, largest accepted value)."""
    require_compliant: bool = True
    """Refuse records of checks run without the admittance controller."""


def record_path(plan_path: str | Path) -> Path:
    """Default check record beside a plan: ``plan.json`` -> ``plan.check.json``."""
    return Path(plan_path).with_suffix(".check.json")


def sha256_tree(folder: str | Path) -> str:
    """sha256 over the relative paths and bytes of every file under a folder (sorted): the scene or twin
    folder a check ran in, so that an edited mesh or joint changes the hash."""
    folder = Path(folder)
    digest = hashlib.sha256()
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        digest.update(str(path.relative_to(folder)).encode() + b"\0")
        digest.update(sha256_file(path).encode())
    return digest.hexdigest()


def _finite(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else round(float(value), 6)


def criteria(report: CheckReport, config: CheckConfig, joint_type: str) -> list[dict[str, Any]]:
    """Every pass criterion with its threshold, unit, measured value (None where the report keeps none) and
    verdict, in ``funrec_robot.check.CRITERIA`` order."""
    failed = {f.criterion for f in report.failures}
    tolerance = config.revolute_tolerance if joint_type == "revolute" else config.prismatic_tolerance
    rows = [
        ("target", tolerance, "rad" if joint_type == "revolute" else "m", report.target_error),
        ("collision", 0.0, "contacts", float(len(report.collisions))),
        ("handle_force", config.max_handle_force, "N", report.peak_handle_force),
        ("joint_position", config.position_tolerance, "rad or m over limit", None),
        ("joint_velocity", 1.0 + config.velocity_tolerance, "|qd|/v_max", report.max_velocity_ratio),
        ("joint_effort", config.effort_time, "s over limit", None),
        ("grasp", config.engage_distance, "m (engaged at s)", report.grasp_engaged_time),
    ]
    return [
        {"name": name, "threshold": _finite(threshold), "unit": unit, "measured": _finite(measured), "passed": name not in failed}
        for name, threshold, unit, measured in rows
    ]


def _settings(config: CheckConfig) -> dict[str, Any]:
    def plain(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [plain(v) for v in value]
        if isinstance(value, (float, np.floating)):
            return _finite(float(value))
        return value

    return plain(dataclasses.asdict(config))


def attest(report: CheckReport, plan_path: str | Path, config: CheckConfig) -> dict[str, Any]:
    """The facts a check record signs (see the module docstring)."""
    from funrec import __version__

    plan_path = Path(plan_path)
    plan_json = json.loads(plan_path.read_bytes())
    joint_type = str(plan_json.get("task", {}).get("joint_type", ""))
    scene = Path(report.scene_file)
    return {
        "plan_sha256": sha256_file(plan_path),
        "plan_file": str(plan_path.resolve()),
        "robot": {"file": report.robot_file, "sha256": sha256_file(report.robot_file) if report.robot_file else None},
        "scene": {"file": str(scene), "folder_sha256": sha256_tree(scene.parent) if scene.is_file() else None},
        "joint": report.joint,
        "passed": report.passed,
        "criteria": criteria(report, config, joint_type),
        "settings": _settings(config),
        "funrec_version": __version__,
        "checked_at": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }


def write_check_record(
    report: CheckReport,
    plan_path: str | Path,
    config: CheckConfig = CheckConfig(),  # noqa: B008 (frozen, immutable default)
    path: str | Path | None = None,
    key: SigningKey | None = None,
) -> Path:
    """Write the signed record of a check of ``plan_path`` (the user's key, created on first use)."""
    path = record_path(plan_path) if path is None else Path(path)
    attested = attest(report, plan_path, config)
    write_signed_record(attested, path, key, report.to_json())
    return path


def write_signed_record(attested: dict[str, Any], path: str | Path, key: SigningKey | None = None,
                        report: dict[str, Any] | None = None) -> Path:
    """Sign ``attested`` and write the record to ``path``."""
    key = load_signing_key() if key is None else key
    data = {"format": CHECK_FORMAT, "attested": attested, "signature": sign(attested, key), "report": report or {}}
    return write_text_staged(path, json.dumps(data, indent=1) + "\n")


def verify_check_record(
    record: Any,
    plan_sha256: str,
    trusted: dict[str, str] | None = None,
    policy: CheckPolicy = CheckPolicy(),
    robot_sha256: str | None = None,
    where: str = "check record",
) -> dict[str, Any]:
    """The attested facts of a record, if it is a signed, trusted, passing record of this plan whose check was
    at least as strict as ``policy`` (and, with ``robot_sha256``, of this robot file).

    Raises:
        TrustError: each refusal, saying why (unsigned, forged or edited, untrusted key, another plan, failed,
            loosened thresholds, another robot file).
    """
    if not isinstance(record, dict) or record.get("format") != CHECK_FORMAT:
        found = record.get("format") if isinstance(record, dict) else type(record).__name__
        raise TrustError(f"{where}: not a signed check record (format {found!r}, expected {CHECK_FORMAT!r}); run `funrec-robot check`")
    attested = record.get("attested")
    signer = verify(attested, record.get("signature"), trusted_keys() if trusted is None else trusted, where)
    assert isinstance(attested, dict)  # verify() checked the signature over it
    if attested.get("plan_sha256") != plan_sha256:
        raise TrustError(
            f"{where} is of another plan (sha256 {str(attested.get('plan_sha256'))[:12]}..., this plan {plan_sha256[:12]}...): "
            "the plan was edited after its check; check it again"
        )
    rows = attested.get("criteria")
    if attested.get("passed") is not True or not isinstance(rows, list) or not all(isinstance(r, dict) and r.get("passed") is True for r in rows):
        failed = [str(r.get("name")) for r in rows or [] if isinstance(r, dict) and r.get("passed") is not True]
        raise TrustError(f"{where}: the check failed ({', '.join(failed) or 'passed is not true'}); a failed plan is never run")
    settings = attested.get("settings")
    if not isinstance(settings, dict):
        raise TrustError(f"{where}: no check settings attested")
    for name, largest in policy.limits:
        value = settings.get(name)
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not value <= largest:
            shown = "not judged" if value is None else value
            raise TrustError(f"{where}: check threshold {name} = {shown} is looser than the accepted policy ({largest:g}); "
                             "check again with the default thresholds")
    if policy.require_compliant and settings.get("compliant") is not True:
        raise TrustError(f"{where}: checked without the compliant controller; the accepted policy requires it")
    robot = attested.get("robot") if isinstance(attested.get("robot"), dict) else {}
    if robot_sha256 is not None and robot.get("sha256") != robot_sha256:
        raise TrustError(f"{where}: checked with robot file {robot.get('file')} (sha256 {str(robot.get('sha256'))[:12]}...), "
                         f"not this endpoint's (sha256 {robot_sha256[:12]}...)")
    return dict(attested, signer=signer)


def require_passing_record(plan_path: str | Path, path: str | Path | None = None, trusted: dict[str, str] | None = None,
                           policy: CheckPolicy = CheckPolicy()) -> dict[str, Any]:
    """The check record beside a plan (the whole record, to hand to an endpoint), verified against the plan's
    current bytes (see :func:`verify_check_record`).

    Raises:
        PlanningError: no record; TrustError: a record that does not vouch for these bytes; FormatError: not JSON.
    """
    plan_path = Path(plan_path)
    path = record_path(plan_path) if path is None else Path(path)
    if not path.is_file():
        raise PlanningError(f"{plan_path}: no check record {path}; run `funrec-robot check {plan_path}` first")
    record = read_json_object(path)
    try:
        verify_check_record(record, sha256_file(plan_path), trusted, policy, where=f"{plan_path}: its check record {path}")
    except TrustError:
        raise
    except (TypeError, ValueError) as exc:
        raise FormatError(path, f"malformed check record: {exc}") from None
    return record


__all__ = [
    "CHECK_FORMAT",
    "POLICY_FIELDS",
    "CheckPolicy",
    "attest",
    "criteria",
    "record_path",
    "require_passing_record",
    "sha256_tree",
    "verify_check_record",
    "write_check_record",
    "write_signed_record",
]
