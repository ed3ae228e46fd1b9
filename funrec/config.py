"""Stage configs as frozen dataclasses: field documentation, command-line flags and config files
derived from the one definition of each field."""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import json
import textwrap
import typing
from pathlib import Path
from typing import Any, TypeVar

from funrec.errors import FunrecError

ConfigT = TypeVar("ConfigT")


def field_docs(cls: type) -> dict[str, str]:
    """Attribute docstrings (the string literal under each field) of a dataclass and its bases."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        try:
            source = textwrap.dedent(inspect.getsource(klass))
        except (OSError, TypeError):
            continue
        body = ast.parse(source).body[0]
        assert isinstance(body, ast.ClassDef)
        statements = body.body
        for node, following in zip(statements, statements[1:]):
            if (
                isinstance(node, ast.AnnAssign)
                and isinstance(node.target, ast.Name)
                and isinstance(following, ast.Expr)
                and isinstance(following.value, ast.Constant)
                and isinstance(following.value.value, str)
            ):
                docs[node.target.id] = " ".join(following.value.value.split())
    return docs


def _scalar_type(annotation: Any) -> type | None:
    """bool, int, float or str for simple field annotations; None for anything else."""
    if annotation in (bool, int, float, str):
        return annotation
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    if len(args) == 1 and args[0] in (int, float, str):
        return args[0]
    return None


def add_config_arguments(
    parser: argparse.ArgumentParser, cls: type, prefix: str = "", common: tuple[str, ...] = (), show_all: bool = True
) -> None:
    """Add one ``--field-name`` flag per scalar field of the config dataclass ``cls``.

    Help text and defaults come from the dataclass, so each option is defined once. Fields
    of nested config dataclasses get flags ``--nested-field-name`` in their own group.

    Args:
        parser: the (sub)command's parser.
        cls: the config dataclass.
        prefix: dotted prefix of the field names (for a config nested in another).
        common: dotted field names (e.g. "export.snap_axis_deg") listed first, in a "common
            options" group.
        show_all: False hides the help of every other flag (it is still accepted).
    """
    groups = {prefix: parser.add_argument_group(f"{cls.__name__} options")}
    if common:
        groups["common"] = parser.add_argument_group("common options")
    _add_fields(parser, groups, cls, prefix, cls(), set(common), show_all)


def _add_fields(
    parser: argparse.ArgumentParser, groups: dict[str, Any], cls: type, prefix: str, defaults: Any,
    common: set[str], show_all: bool,
) -> None:
    docs = field_docs(cls)
    hints = typing.get_type_hints(cls)
    group = groups[prefix]
    for field in dataclasses.fields(cls):
        annotation = hints[field.name]
        default = getattr(defaults, field.name)
        if dataclasses.is_dataclass(annotation):
            description = docs.get(field.name) if show_all else None
            groups[f"{prefix}{field.name}."] = parser.add_argument_group(
                f"{field.name} options ({annotation.__name__})", description
            )
            _add_fields(parser, groups, annotation, f"{prefix}{field.name}.", default, common, show_all)
            continue
        kind = _scalar_type(annotation)
        if kind is None:
            continue
        flag = "--" + (prefix + field.name).replace("_", "-").replace(".", "-")
        help_text = f"{docs.get(field.name, '')} (default: {default})".replace("%", "%%")
        target = group
        if prefix + field.name in common:
            target = groups["common"]
        elif not show_all:
            help_text = argparse.SUPPRESS
        if kind is bool:
            target.add_argument(
                flag, dest=prefix + field.name, action=argparse.BooleanOptionalAction, default=argparse.SUPPRESS, help=help_text
            )
        else:
            target.add_argument(
                flag, dest=prefix + field.name, type=kind, default=argparse.SUPPRESS, metavar=kind.__name__.upper(), help=help_text
            )


def config_from_args(cls: type[ConfigT], args: argparse.Namespace, base: ConfigT | None = None) -> ConfigT:
    """Build a config from flags added by :func:`add_config_arguments`; fields whose flag was not
    given keep the value of ``base`` (default: ``cls()``), e.g. of a ``--config`` file (the flags
    have no argparse default, so an absent flag cannot overwrite the file's value)."""
    return _replace_from(vars(args), cls, base if base is not None else cls(), "")


def _replace_from(values: dict[str, Any], cls: type, config: Any, prefix: str) -> Any:
    hints = typing.get_type_hints(cls)
    changes: dict[str, Any] = {}
    for field in dataclasses.fields(cls):
        annotation = hints[field.name]
        if dataclasses.is_dataclass(annotation):
            changes[field.name] = _replace_from(
                values, annotation, getattr(config, field.name), f"{prefix}{field.name}."
            )
        elif prefix + field.name in values:
            changes[field.name] = values[prefix + field.name]
    return dataclasses.replace(config, **changes)


def config_to_dict(config: Any) -> dict[str, Any]:
    """A (nested) config as plain JSON-able data that :func:`config_from_dict` reads back."""

    def plain(value: Any) -> Any:
        if isinstance(value, (tuple, list)):
            return [plain(v) for v in value]
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        return value

    return {k: plain(v) for k, v in dataclasses.asdict(config).items()}


def config_from_dict(cls: type[ConfigT], data: dict[str, Any], source: str = "config") -> ConfigT:
    """Build a (nested) config from a dictionary, rejecting unknown keys by name."""
    known = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise FunrecError(f"{source}: unknown keys {unknown} for {cls.__name__}; valid keys: {sorted(known)}")
    hints = typing.get_type_hints(cls)
    kwargs: dict[str, Any] = {}
    for name, value in data.items():
        annotation = hints[name]
        if dataclasses.is_dataclass(annotation):
            if not isinstance(value, dict):
                raise FunrecError(f"{source}: {name} must be a mapping of {annotation.__name__} fields")
            kwargs[name] = config_from_dict(annotation, value, f"{source}.{name}")  # type: ignore[arg-type]
        else:
            kwargs[name] = tuple(value) if isinstance(value, list) else value
    return dataclasses.replace(cls(), **kwargs)  # type: ignore[call-arg]


def load_config_file(cls: type[ConfigT], path: str | Path) -> ConfigT:
    """Read a JSON or YAML config file into ``cls`` (unknown keys are an error)."""
    path = Path(path)
    if not path.is_file():
        raise FunrecError(f"{path}: config file does not exist")
    text = path.read_text()
    if path.suffix.lower() in (".yaml", ".yml"):
        import yaml

        data = yaml.safe_load(text) or {}
    else:
        data = json.loads(text)
    if not isinstance(data, dict):
        raise FunrecError(f"{path}: expected a mapping at the top level")
    return config_from_dict(cls, data, str(path))


__all__ = [
    "add_config_arguments",
    "config_from_args",
    "config_from_dict",
    "config_to_dict",
    "field_docs",
    "load_config_file",
]
