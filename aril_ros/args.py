"""ROS launch-style ``key:=value`` arguments parsed into a dataclass.

Each argument dataclass declares its fields with :func:`arg`, which carries the help text, so
``--help`` lists every argument with its type, default and meaning.
"""
from __future__ import annotations

import dataclasses
import shlex
import typing


def arg(default, help: str):
    """A dataclass field with a default and a help text."""
    return dataclasses.field(default=default, metadata={"help": help})


class ArgumentError(ValueError):
    """A ``key:=value`` argument is malformed, unknown, or of the wrong type."""


def _convert(name: str, text: str, kind):
    if kind is bool:
        if text.lower() in ("true", "1", "yes", "on"):
            return True
        if text.lower() in ("false", "0", "no", "off"):
            return False
        raise ArgumentError(f"{name}:= takes true or false, got {text!r}")
    try:
        return kind(text)
    except ValueError:
        raise ArgumentError(f"{name}:= takes {kind.__name__}, got {text!r}") from None


def parse_args(cls, argv: list[str]):
    """Build ``cls`` from ``["key:=value", ...]``; raises :class:`ArgumentError` with the fix."""
    types = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    values = {}
    for item in argv:
        key, sep, text = item.partition(":=")
        if not sep or not key:
            raise ArgumentError(f"arguments are key:=value, got {item!r} (see --help)")
        if key not in names:
            raise ArgumentError(f"unknown argument {key!r}; known: {', '.join(names)}")
        values[key] = _convert(key, text, types[key])
    return cls(**values)


def command_line(prog: str, cfg) -> str:
    """The command that reproduces ``cfg`` (recorded in the provenance of what it makes)."""
    return prog + " " + " ".join(f"{f.name}:={shlex.quote(str(getattr(cfg, f.name)))}"
                                 for f in dataclasses.fields(cfg) if getattr(cfg, f.name) != "")


def usage(cls, prog: str, summary: str) -> str:
    lines = [f"usage: {prog} [key:=value ...]", "", summary, "", "arguments:"]
    for f in dataclasses.fields(cls):
        lines.append(f"  {f.name + ':=':<16} {f.metadata.get('help', '')} (default: {f.default!r})")
    return "\n".join(lines)


def comma_list(text: str) -> list[str]:
    """``a,b,c`` as a list (empty items dropped)."""
    return [x for x in text.split(",") if x]
