"""What every trained file and table records about how it was made.

A provenance record holds the command that reproduces the file (for a person to read and rerun) and
the same settings as JSON (``settings``, for a program to read back: :func:`settings_of`), the git
revision, the versions of the simulator and its kin, and the time; trainings add their own figures
beside these.
"""
from __future__ import annotations

import dataclasses
import datetime
import functools
import platform
import subprocess
from importlib import metadata
from pathlib import Path

from .args import command_line


def git_revision() -> str:
    """The short revision of the checkout this package runs from, or ``unknown`` (an installed copy)."""
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=Path(__file__).resolve().parent,
                             capture_output=True, text=True, timeout=5)
        return out.stdout.strip() or "unknown"
    except OSError:
        return "unknown"


def now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def versions() -> dict:
    """The versions of what decides a trajectory: a new MuJoCo or gymnasium changes returns as much as new code,
    and so does the CPU: torch picks its matrix kernels by the instruction set, and they round differently, so
    the same files give other episodes on another CPU model (bit-identical on one machine)."""
    return {**{name: metadata.version(name) for name in ("mujoco", "gymnasium", "numpy", "torch")}, "cpu": cpu()}


@functools.cache  # a process stays on its CPU; every evaluation task and every stamp asks
def cpu() -> str:
    """The CPU model and the instruction set torch's kernels use on it, e.g. ``AMD EPYC (AVX512)``."""
    import torch  # here, not at the top: most readers of a provenance never run a policy

    model = next((line.split(":", 1)[1].strip() for line in _cpuinfo().splitlines()
                  if line.startswith("model name")), platform.processor() or platform.machine())
    return f"{model} ({torch.backends.cpu.get_cpu_capability()})"


def _cpuinfo() -> str:
    try:
        return Path("/proc/cpuinfo").read_text()
    except OSError:  # not Linux
        return ""


CHECKOUT = Path(__file__).resolve().parents[1]
"""The folder holding the ``aril_ros`` package: a checkout's root, from which recorded paths are read."""


def portable(value):
    """``value`` as it is, unless it is an absolute path inside :data:`CHECKOUT`: then that path relative to it.
    The bundled files and tables are committed and read on other machines, where this machine's folder means
    nothing (``aril defense-table`` hands the trainer the bundled victim's absolute path, for one)."""
    if isinstance(value, str) and Path(value).is_absolute() and Path(value).is_relative_to(CHECKOUT):
        return str(Path(value).relative_to(CHECKOUT))
    return value


def stamp(prog: str, cfg) -> dict:
    """``command``, ``settings``, ``git_revision``, ``versions`` and ``created`` for a run of ``prog`` with ``cfg``,
    its paths inside the checkout relative to it (:func:`portable`)."""
    cfg = dataclasses.replace(cfg, **{f.name: portable(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)})
    return {"command": command_line(prog, cfg), "settings": dataclasses.asdict(cfg), "git_revision": git_revision(),
            "versions": versions(), "created": now()}


def settings_of(provenance: dict, cls, **changes):
    """The ``cls`` arguments a file was made with (its provenance's ``settings``), with ``changes``;
    settings added to ``cls`` since the file was made take their defaults."""
    if "settings" not in provenance:
        raise ValueError(f"the file records no settings (made by {provenance.get('command', 'an unknown command')!r})")
    known = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in provenance["settings"].items() if k in known} | changes)
