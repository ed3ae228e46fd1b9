"""Find robot YAML files: the project's ``robots/`` folder, a folder of the user's, or a path."""

from __future__ import annotations

from pathlib import Path

from funrec_robot.errors import RobotDescriptionError, format_names

DEFAULT_ROBOT = "funrec_mm"
"""Name of the robot FunREC plans for when none is given (``robots/funrec_mm.yaml``)."""


def robots_dir() -> Path:
    """The project's ``robots/`` folder, beside the ``funrec_robot`` package in the source tree."""
    return Path(__file__).resolve().parents[1] / "robots"


def find_robots(directory: str | Path | None = None) -> tuple[Path, ...]:
    """Robot YAML files in a folder, sorted by name.

    Args:
        directory: folder to search; None for :func:`robots_dir`.

    Returns:
        The ``*.yaml`` files directly in it.

    Raises:
        RobotDescriptionError: the folder does not exist.
    """
    folder = robots_dir() if directory is None else Path(directory)
    if not folder.is_dir():
        raise RobotDescriptionError(folder, "no such robots folder (pass a robot YAML file or --dir)")
    return tuple(sorted(folder.glob("*.yaml")))


def resolve_robot(name_or_path: str | Path, directory: str | Path | None = None) -> Path:
    """The YAML file of a robot given by path or by name.

    Args:
        name_or_path: an existing YAML file, or the stem of one in ``directory`` (``fetch``).
        directory: folder of named robots; None for :func:`robots_dir`.

    Raises:
        RobotDescriptionError: neither; the message lists the robots available by name.
    """
    path = Path(name_or_path)
    if path.is_file():
        return path
    available = find_robots(directory)
    for candidate in available:
        if candidate.stem == str(name_or_path):
            return candidate
    folder = robots_dir() if directory is None else Path(directory)
    raise RobotDescriptionError(
        path, f"no such robot YAML file or robot name; robots in {folder}: {format_names(p.stem for p in available)}"
    )


def default_robot_path() -> Path:
    """``robots/funrec_mm.yaml``, the default robot's description."""
    return resolve_robot(DEFAULT_ROBOT)


__all__ = ["DEFAULT_ROBOT", "default_robot_path", "find_robots", "resolve_robot", "robots_dir"]
