"""The ``funrec-robot`` command line: thin handlers over the funrec_robot API.

Exit codes: 0 success, 2 bad input or an impossible request (one line on stderr, the
traceback with --verbose), 1 a bug (traceback), 3 a plan that was checked and failed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from funrec.cli_runner import run_command
from funrec.errors import FunrecError

log = logging.getLogger("funrec_robot")

EXIT_CHECK_FAILED = 3
"""``funrec-robot check`` ran and the plan failed a criterion."""


def _number_or_word(text: str) -> str | float:
    try:
        return float(text)
    except ValueError:
        return text


def _cmd_robots(args: argparse.Namespace) -> int:
    from funrec_robot.catalog import find_robots, robots_dir
    from funrec_robot.describe import robot_summary
    from funrec_robot.robot import load_robot

    folder = args.dir if args.dir is not None else robots_dir()
    paths = find_robots(folder)
    for path in paths:
        try:
            print(f"{robot_summary(load_robot(path))}  [{path}]")
        except FunrecError as exc:  # one broken or uninstalled robot must not hide the others
            print(f"{path.stem}: unavailable: {exc}")
    print(f"{len(paths)} robot files in {folder}")
    return 0


def _cmd_describe(args: argparse.Namespace) -> int:
    if args.render:
        os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported: headless rendering
    from funrec_robot.catalog import resolve_robot
    from funrec_robot.describe import format_robot
    from funrec_robot.robot import load_robot

    robot = load_robot(resolve_robot(args.robot, args.dir))
    print(format_robot(robot))
    if args.render:
        from funrec_robot.render import render_robot

        print(f"home pose rendered to {render_robot(robot, args.render, args.width, args.height)}")
    return 0


def _add_robots(sub: Any) -> None:
    p = sub.add_parser(
        "robots",
        help="list the robot YAML files and their degrees of freedom",
        description="Load every robot YAML file in the robots folder (default: the project's robots/) and "
        "print its planning degrees of freedom, base type and gripper; a robot that cannot be loaded is "
        "listed with the reason.",
    )
    p.add_argument("--dir", type=Path, help="folder of robot YAML files (default: the project's robots/)")
    p.set_defaults(handler=_cmd_robots)


def _add_describe(sub: Any) -> None:
    p = sub.add_parser(
        "describe",
        help="print a robot's joints, limits, end effector and gripper",
        description="Load a robot YAML file, check it against its model and print the planning joints with "
        "their position, speed, acceleration and effort limits and home pose, the end-effector site and "
        "grasp frame, the gripper and what the simulation adds.",
    )
    p.add_argument("robot", help="robot YAML file, or the name of one in the robots folder (e.g. funrec_mm)")
    p.add_argument("--dir", type=Path, help="folder of named robots (default: the project's robots/)")
    p.add_argument("--render", type=Path, metavar="PNG", help="also render the home pose with MuJoCo to this PNG")
    p.add_argument("--width", type=int, default=640, help="--render image width in pixels (default: 640)")
    p.add_argument("--height", type=int, default=480, help="--render image height in pixels (default: 480)")
    p.set_defaults(handler=_cmd_describe)


def _cmd_plan(args: argparse.Namespace) -> int:
    from funrec.config import config_from_args
    from funrec_robot.catalog import resolve_robot
    from funrec_robot.plan import PlanConfig, plan_scene
    from funrec_robot.plan_file import write_plan

    config = config_from_args(PlanConfig, args)
    start = None if args.start is None else float(args.start)
    plan = plan_scene(resolve_robot(args.robot), args.scene, args.part, _number_or_word(args.to), start, config)
    write_plan(args.output, plan)
    p = plan.provenance
    print(
        f"plan for {plan.part} ({plan.joint_type}) {plan.start_state:.3f} -> {plan.target_state:.3f}: {plan.duration:.2f} s, "
        f"{len(plan.base_poses)} base stop(s), planned in {p['plan_time_s']:.2f} s, written to {args.output}"
    )
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    if args.video:
        from funrec.offscreen import ensure_gl_backend

        ensure_gl_backend()  # before mujoco is imported: headless video
    from funrec.config import config_from_args
    from funrec_robot.catalog import resolve_robot
    from funrec_robot.check import CheckConfig, check_plan_file

    config = config_from_args(CheckConfig, args)
    if args.no_force_limit:
        config = dataclasses.replace(config, max_handle_force=None)
    robot = None if args.robot is None else resolve_robot(args.robot)
    from funrec_robot.check_record import write_check_record

    report = check_plan_file(args.plan, args.scene, args.joint, args.gt, robot, config, args.video)
    report_path = write_check_record(report, args.plan, config, args.report)
    verdict = "PASS" if report.passed else "FAIL (" + ", ".join(f"{f.criterion} at {f.time:.2f} s" for f in report.failures) + ")"
    print(
        f"{verdict}: {report.joint} ended at {report.final_state:.3f} (target {report.target_state:.3f}), peak handle force "
        f"{report.peak_handle_force:.1f} N; report {report_path}" + (f", video {report.video}" if report.video else "")
    )
    return 0 if report.passed else EXIT_CHECK_FAILED


def _cmd_bench(args: argparse.Namespace) -> int:
    from funrec_robot.bench import bench_suite, summarize
    from funrec_robot.catalog import resolve_robot

    def show(row: Any) -> None:
        status = "PASS" if row.passed else ("FAIL" if row.planned else ("REFUSED" if row.refused else "NO PLAN"))
        print(f"{row.case:24s} {row.part:8s} {status:7s} plan {row.plan_cpu_time:5.2f} s CPU  force {row.peak_handle_force:5.1f} N  "
              f"{row.failure[:110]}")

    rows = bench_suite(args.suite, resolve_robot(args.robot), args.to, args.only or (), plans_dir=args.plans, progress=show,
                       twins=args.twins)
    summary = summarize(rows)
    if args.output:
        Path(args.output).write_text(json.dumps(summary, indent=1) + "\n")
    for family, part in summary["families"].items():
        print(f"  {family:10s} {part['passed']}/{part['accepted']} accepted passed, {part['refused']} refused; "
              f"plan CPU median {part['median_plan_cpu_time_s']:.2f} s, p95 {part['p95_plan_cpu_time_s']:.2f} s")
    print(
        f"{summary['passed']}/{summary['parts']} passed ({summary['planned']} planned; {summary['passed']}/{summary['accepted']} "
        f"of the parts accepted, {summary['refused']} refused); plan CPU time median {summary['median_plan_cpu_time_s']:.2f} s, "
        f"p95 {summary['p95_plan_cpu_time_s']:.2f} s (wall median {summary['median_plan_time_s']:.2f} s); peak handle force "
        f"median {summary['median_peak_handle_force_N']:.1f} N, max {summary['max_peak_handle_force_N']:.1f} N; "
        f"plans with collisions {summary['plans_with_collisions']}"
    )
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    from funrec.offscreen import ensure_gl_backend

    if not args.no_video:
        ensure_gl_backend()  # before mujoco is imported: headless video
    from funrec_robot.catalog import resolve_robot
    from funrec_robot.replay import replay_twin

    def show(step: Any) -> None:
        hold = step.interaction
        status = "PASS" if step.passed else ("FAIL" if step.planned else "NO PLAN")
        print(f"{hold.t_start:7.2f} s  {hold.part:8s} hold {hold.index}  {status:7s} {step.failure[:110]}")

    output = args.output if args.output is not None else Path(args.twin) / "replay"
    report = replay_twin(resolve_robot(args.robot), args.twin, output, args.gt, video=not args.no_video, progress=show)
    print(f"{report['passed']}/{report['interactions']} interactions passed; report {output / 'replay.json'}"
          + (f", video {report['video']}" if report["video"] else ""))
    return 0 if report["all_passed"] else EXIT_CHECK_FAILED


def _cmd_send(args: argparse.Namespace) -> int:
    from funrec_robot.check_record import require_passing_record
    from funrec_robot.driver import send_plan

    require_passing_record(args.plan)  # refuse before connecting (send_plan verifies again)
    driver = None if args.to.startswith("ros2://") else _connect(args)
    try:
        result = send_plan(args.plan, args.to, timeout=args.timeout, driver=driver)
    finally:
        if driver is not None:
            driver.close()
    print(f"{result.event}: {result.detail} ({result.wall_time:.1f} s, plan {result.plan_id[:12]})")
    return 0 if result.event == "done" else EXIT_CHECK_FAILED


def _cmd_serve_sim(args: argparse.Namespace) -> int:
    from funrec.config import config_from_args
    from funrec_robot.catalog import resolve_robot
    from funrec_robot.endpoint import return_large_buffers_to_the_os, short_turns
    from funrec_robot.protocol import PROTOCOL
    from funrec_robot.robot import load_robot
    from funrec_robot.sim_server import SimServerConfig, make_sim_server

    return_large_buffers_to_the_os()
    server = make_sim_server(load_robot(resolve_robot(args.robot)), args.scene, config_from_args(SimServerConfig, args))
    short_turns()  # after the robot is built: its objects are frozen out of the garbage collector's walks
    host, port = server.server_address[:2]
    security = f"TLS, certificate {server.certificate}" if server.ssl is not None else "NO TLS, NO AUTHENTICATION"
    print(f"serving {server.sim.robot.name} ({PROTOCOL}, {security}) on {host}:{port}; Ctrl-C to stop", flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    return 0


def _connect(args: argparse.Namespace) -> Any:
    """A funrec-robot/2 client from --to, --server-cert, --token-file and --no-tls."""
    from funrec_robot.driver import TcpDriver

    token = args.token_file.read_text().strip() if args.token_file is not None else None
    return TcpDriver(args.to, tls=not args.no_tls, server_cert=args.server_cert, token=token)


def _cmd_estop(args: argparse.Namespace) -> int:
    driver = _connect(args)
    try:
        status = driver.request("estop")["status"]
    finally:
        driver.close()
    print(f"E-Stop sent: the robot is {status}")
    return 0


def _cmd_keys(args: argparse.Namespace) -> int:
    from funrec_robot.keys import config_dir, export_public, fingerprint, load_signing_key, trust_key, trusted_keys
    from funrec_robot.tls import CERT_FILE, authorize_token, client_token

    if args.trust:
        path = trust_key(args.trust, args.label)
        print(f"trusted {fingerprint(args.trust.split()[0].lower())}: {path}")
        return 0
    if args.authorize_token:
        print(f"authorized a token: {authorize_token(args.authorize_token, args.label)}")
        return 0
    key = load_signing_key()
    if args.export:
        print(export_public(key))
        return 0
    if args.show_token:
        print(client_token())
        return 0
    print(f"folder {config_dir()}")
    print(f"signing key {fingerprint(key.public_hex)} (public {key.public_hex})")
    for public, label in trusted_keys().items():
        print(f"trusted {fingerprint(public)} {label}")
    cert = config_dir() / CERT_FILE
    print(f"endpoint certificate {cert if cert.is_file() else '(none yet: serve-sim creates it)'}")
    return 0


def _default_robot() -> str:
    from funrec_robot.catalog import DEFAULT_ROBOT

    return DEFAULT_ROBOT


def _add_plan(sub: Any) -> None:
    from funrec.config import add_config_arguments
    from funrec_robot.plan import PlanConfig

    p = sub.add_parser(
        "plan",
        help="plan a mobile manipulator opening or closing one articulated part",
        description="Place the base (casadi), follow the handle with whole-body IK (mink), time the motion (toppra "
        "along the handle, ruckig between states) and write plan.json. SCENE is an MJCF scene with gt.json "
        "(synthetic ground truth) or articulation.json + affordances.json (a twin) beside it, or such a folder.",
    )
    p.add_argument("--scene", required=True, help="scene: gt/ or capture folder, twin folder, or their MJCF file")
    p.add_argument("--part", help="part (joint) name; may be omitted when the scene has one part")
    p.add_argument("--to", default="open", help="target: open, close, demo or a joint state in rad or m (default: open)")
    p.add_argument("--from", dest="start", help="the part's state when the robot arrives (default: the scene's)")
    p.add_argument("--robot", default=_default_robot(), help="robot YAML file or name (default: %(default)s)")
    p.add_argument("-o", "--output", type=Path, required=True, help="plan.json to write")
    add_config_arguments(p, PlanConfig)
    p.set_defaults(handler=_cmd_plan)


def _add_check(sub: Any) -> None:
    from funrec.config import add_config_arguments
    from funrec_robot.check import CheckConfig

    p = sub.add_parser(
        "check",
        help="execute a plan in MuJoCo and judge it (exit 0 only on pass)",
        description="Run plan.json on the robot's servos with an admittance law on the handle wrench; the grasp is an "
        "equality attachment that engages only when the closed gripper is at the handle. Passes if the joint ends within "
        "5 deg / 2 cm of the target, no robot-scene contact other than gripper and handle, peak handle force within the "
        "bound, no joint position, velocity or effort limit violated. Writes a JSON report; exit 3 on failure.",
    )
    p.add_argument("plan", type=Path, help="plan.json")
    p.add_argument("--scene", help="scene to check in (default: --gt's scene.xml, else the plan's scene)")
    p.add_argument("--joint", help="joint of the checked scene the plan operates (default: the plan's part)")
    p.add_argument("--gt", type=Path, help="ground-truth folder: check in its scene.xml, mapping a twin's frame through camera 0")
    p.add_argument("--robot", help="robot YAML file (default: the plan's)")
    p.add_argument("--no-force-limit", action="store_true", help="do not judge the handle force")
    p.add_argument("--video", type=Path, help="write an MP4 (or .gif) of the execution")
    p.add_argument("--report", type=Path, help="report JSON (default: PLAN.check.json)")
    add_config_arguments(p, CheckConfig)
    p.set_defaults(handler=_cmd_check)


def _add_bench(sub: Any) -> None:
    p = sub.add_parser(
        "bench",
        help="plan and check every part of a folder of synthetic captures",
        description="For each capture with gt/ under SUITE, plan the target for every part in its ground-truth scene "
        "and check it there; print one line per part and a summary (success rate, plan time, handle force, collisions).",
    )
    p.add_argument("suite", type=Path, help="folder of capture folders (e.g. bench_suite)")
    p.add_argument("--robot", default=_default_robot(), help="robot YAML file or name (default: %(default)s)")
    p.add_argument("--to", default="open", help="target of every plan (default: open)")
    p.add_argument("--only", nargs="*", help="capture names to restrict to")
    p.add_argument("--plans", type=Path, help="folder to write the plans to")
    p.add_argument("--twins", type=Path, help="plan on the reconstructed twins TWINS/<capture> (e.g. bench_report/twins/funrec) "
                   "and check each plan in the capture's ground-truth scene")
    p.add_argument("-o", "--output", type=Path, help="write the summary and rows as JSON")
    p.set_defaults(handler=_cmd_bench)


def _add_replay(sub: Any) -> None:
    p = sub.add_parser(
        "replay",
        help="plan and check every interaction demonstrated in a twin, in order",
        description="For each hold in the twin's affordances.json, in time order, plan the demonstrated joint "
        "trajectory (--to demo) from the state it started at and check it in the twin (or in --gt's true scene). "
        "Writes the plans with their check records, replay.json and one replay.mp4; exit 3 unless all pass.",
    )
    p.add_argument("twin", type=Path, help="twin folder (articulation.json, affordances.json, twin.xml)")
    p.add_argument("--robot", default=_default_robot(), help="robot YAML file or name (default: %(default)s)")
    p.add_argument("--gt", type=Path, help="ground-truth folder: check in its scene.xml, mapping the twin through camera 0")
    p.add_argument("-o", "--output", type=Path, help="output folder (default: TWIN/replay)")
    p.add_argument("--no-video", action="store_true", help="do not render the video")
    p.set_defaults(handler=_cmd_replay)


def _cmd_reach(args: argparse.Namespace) -> int:
    from funrec_robot.catalog import resolve_robot
    from funrec_robot.reach import reach_table

    names, rows = reach_table(args.scene, [resolve_robot(r) for r in args.robot])
    width = max(8, *(len(n) for n in names))
    print(f"{'part':10s} {'handle':>7s}  " + "  ".join(f"{n:{width}s}" for n in names))
    for row in rows:
        cells = "  ".join(f"{'yes' if r is None else 'no':{width}s}" for r in row.refusals)
        print(f"{row.part:10s} {row.height:6.2f}m  {cells}")
    for row in rows:
        for name, why in zip(names, row.refusals):
            if why is not None:
                print(f"{row.part} / {name}: {why}")
    return 0


def _add_reach(sub: Any) -> None:
    p = sub.add_parser(
        "reach",
        help="tabulate which robots can reach which parts of a scene",
        description="For every part of SCENE (twin folder, gt/ or capture folder, or their MJCF) and every robot, "
        "whether the handle lies within the heights the robot's hand reaches (arm, lift or torso range); the "
        "planner refuses the others at once with the sentence printed here.",
    )
    p.add_argument("scene", help="scene: twin folder, gt/ or capture folder, or their MJCF file")
    p.add_argument("--robot", nargs="+", default=[_default_robot()], help="robot YAML files or names (default: %(default)s)")
    p.set_defaults(handler=_cmd_reach)


class _ModelsFolder(argparse.Action):
    """``--models DIR``: the robot models folder robot files name as ``models://`` (sets FUNREC_ROBOT_MODELS)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option_string: str | None = None) -> None:
        from funrec_robot.robot_yaml import MODELS_ENV

        os.environ[MODELS_ENV] = str(values)
        setattr(namespace, self.dest, values)


def _add_send(sub: Any) -> None:
    p = sub.add_parser(
        "send",
        help="send a checked plan to a robot endpoint and run it",
        description="Refuses a plan without a signed, trusted, passing check record of its exact bytes (PLAN.check.json "
        "from `funrec-robot check`). Connects over TLS, authenticates, takes the lease, uploads, starts, sends heartbeats "
        "and waits for the end. ADDRESS: host:port of a funrec-robot/2 endpoint (e.g. serve-sim) or ros2://NAMESPACE "
        "(FollowJointTrajectory; needs rclpy). Exit 0 when the robot reports done, 3 when it stopped or faulted.",
    )
    p.add_argument("plan", type=Path, help="plan.json (its .check.json beside it)")
    p.add_argument("--to", required=True, metavar="ADDRESS", help="endpoint: host:port, tcp://host:port or ros2://NAMESPACE")
    p.add_argument("--timeout", type=float, help="stop the robot after this many seconds (default: duration + 30 s)")
    _add_connection_arguments(p)
    p.set_defaults(handler=_cmd_send)


def _add_connection_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--server-cert", type=Path, help="the endpoint's certificate to pin (default: this machine's endpoint's)")
    p.add_argument("--token-file", type=Path, help="file holding the token to present (default: this user's)")
    p.add_argument("--no-tls", action="store_true", help="plain TCP to an endpoint started with --no-auth (loopback experiments)")


def _add_serve_sim(sub: Any) -> None:
    from funrec.config import add_config_arguments
    from funrec_robot.sim_server import SimServerConfig

    p = sub.add_parser(
        "serve-sim",
        help="a simulated robot endpoint (funrec-robot/2 over TLS) that runs plans in MuJoCo in real time",
        description="Listen for funrec-robot/2 clients (docs/robot_protocol.md): TLS, token or client-certificate "
        "authentication, one lease holder who may upload, start and stop, E-Stop from any authenticated client, "
        "the holder's heartbeat, state stream. Plans need a signed check record from a trusted key and are validated "
        "against this robot file's limits and run on its servos in real time.",
    )
    p.add_argument("--robot", default=_default_robot(), help="robot YAML file or name (default: %(default)s)")
    p.add_argument("--scene", type=Path, help="MJCF scene to stand the robot in (default: an empty world)")
    add_config_arguments(p, SimServerConfig)
    p.set_defaults(handler=_cmd_serve_sim)


def _add_estop(sub: Any) -> None:
    p = sub.add_parser(
        "estop",
        help="E-Stop a funrec-robot/2 endpoint (any authenticated client, lease or not)",
        description="Connect, authenticate and send an E-Stop: whatever runs stops and holds, status fault.",
    )
    p.add_argument("--to", required=True, metavar="ADDRESS", help="endpoint: host:port or tcp://host:port")
    _add_connection_arguments(p)
    p.set_defaults(handler=_cmd_estop)


def _add_keys(sub: Any) -> None:
    p = sub.add_parser(
        "keys",
        help="show, export and trust check-record signing keys; authorize client tokens",
        description="Keys live in $XDG_CONFIG_HOME/funrec-robot/ (created on first use; private files mode 0600). "
        "Without options: show this user's signing key, the trusted keys and the endpoint certificate.",
    )
    group = p.add_mutually_exclusive_group()
    group.add_argument("--export", action="store_true", help="print this user's public signing key for another machine")
    group.add_argument("--trust", metavar="HEX", help="trust records signed by this public key (64 hex digits)")
    group.add_argument("--authorize-token", metavar="TOKEN", help="let this machine's endpoint accept this client token")
    group.add_argument("--show-token", action="store_true", help="print this user's client token (a secret)")
    p.add_argument("--label", default="", help="a name for the trusted key or token")
    p.set_defaults(handler=_cmd_keys)


_COMMANDS: tuple[Callable[[Any], None], ...] = (
    _add_robots, _add_describe, _add_plan, _add_check, _add_bench, _add_replay, _add_send, _add_serve_sim, _add_estop, _add_keys,
    _add_reach,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="funrec-robot",
        description="FunREC robots: describe the mobile manipulators that replay reconstructed interactions, plan "
        "their interactions with articulated parts and check the plans in simulation.",
    )
    parser.add_argument("--models", action=_ModelsFolder, metavar="DIR",
                        help="folder of third-party robot models that robot files name as models://... "
                        "(default: the environment variable FUNREC_ROBOT_MODELS)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in _COMMANDS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    return run_command(build_parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
