"""ROS launch-style ``key:=value`` arguments parsed into a dataclass.

Each argument dataclass declares its fields with :func:`arg`, which carries the help text, so
``--help`` lists every argument with its type, default and meaning.
"""
from __future__ import annotations

import dataclasses
import shlex
import sys
import typing


def arg(default, help: str, low=None, high=None):
    """A dataclass field with a default, a help text and, for a number, the range ``low..high`` (either
    end optional) that :func:`check_ranges` holds it to."""
    return dataclasses.field(default=default, metadata={"help": help, "low": low, "high": high})


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
    return check_ranges(cls(**values))


def _range_text(field) -> str:
    low, high = field.metadata.get("low"), field.metadata.get("high")
    if low is None or high is None:
        return "" if low is None and high is None else f">= {low}" if high is None else f"<= {high}"
    return f"{low}..{high}"


def check_ranges(cfg):
    """``cfg`` itself, once every number is within the range its field declares (a NaN is within none);
    raises :class:`ArgumentError` naming the argument, the value and the range."""
    for field in dataclasses.fields(cfg):
        low, high, value = field.metadata.get("low"), field.metadata.get("high"), getattr(cfg, field.name)
        if not ((low is None or value >= low) and (high is None or value <= high)):
            raise ArgumentError(f"{field.name}:={value} is out of range: allowed {_range_text(field)}")
    return cfg


def command_line(prog: str, cfg) -> str:
    """The command that reproduces ``cfg`` (recorded in the provenance of what it makes)."""
    return prog + " " + " ".join(f"{f.name}:={shlex.quote(str(getattr(cfg, f.name)))}"
                                 for f in dataclasses.fields(cfg) if getattr(cfg, f.name) != "")


def usage(cls, prog: str, summary: str) -> str:
    lines = [f"usage: {prog} [key:=value ...]", "", summary, "", "arguments:"]
    for f in dataclasses.fields(cls):
        allowed = f"; allowed {_range_text(f)}" if _range_text(f) else ""
        lines.append(f"  {f.name + ':=':<16} {f.metadata.get('help', '')} (default: {f.default!r}{allowed})")
    return "\n".join(lines)


def module_config(cls, prog: str, doc: str, argv: list[str]):
    """A ``python -m`` module's arguments: ``cls`` from ``argv``, or None once the usage is printed (``--help``,
    ``-h``; its summary is the first line of the module's ``doc``). A refused argument ends the process with one
    line and exit 2, as ``aril`` does."""
    if "--help" in argv or "-h" in argv:
        print(usage(cls, prog, doc.strip().splitlines()[0]))
        return None
    try:
        return parse_args(cls, argv)
    except ArgumentError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        raise SystemExit(2) from None


def comma_list(text: str) -> list[str]:
    """``a,b,c`` as a list (empty items dropped)."""
    return [x for x in text.split(",") if x]
