"""The ``funrec-robot`` command line: thin handlers over the funrec_robot API.

Exit codes: 0 success, 2 bad input or an impossible request (one line on stderr, the
traceback with --verbose), 1 a bug (traceback).
"""

from __future__ import annotations

import argparse
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from funrec.cli_runner import run_command
from funrec.errors import FunrecError

log = logging.getLogger("funrec_robot")


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


_COMMANDS: tuple[Callable[[Any], None], ...] = (_add_robots, _add_describe)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="funrec-robot",
        description="FunREC robots: describe the mobile manipulators that replay reconstructed interactions.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log detail and show tracebacks of errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in _COMMANDS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    return run_command(build_parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
