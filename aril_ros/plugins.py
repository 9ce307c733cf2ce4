"""What other packages add to the library, found by name at run time: the library never imports them.

The ROS 2 side (``aril_ros_nodes``, installed from ``nodes/``) registers itself through Python entry
points in ``pyproject.toml``, so the arrows go one way only, from the ROS side to the library:

- ``aril_ros.commands``: subcommands of ``aril`` (an object with ``config``, ``run`` and ``summary``);
  ``replay`` is one.
- ``aril_ros.collectors``: where ``train-learner source:=<name>`` collects a round and ``scorecard via:=<name>``
  runs a cell (``graph``: through the ROS 2 nodes); a function ``collect(spec: aril_ros.collectors.RoundSpec) -> Path``
  that runs the episodes ``spec`` describes, records them to ``spec.record`` and returns that path: the library
  reads the run log back (:func:`aril_ros.runlog.read_run`: the steps, and each episode's figures).
- ``aril_ros.victims``: ``train-adversary victim:=<name>`` attacks a policy reached elsewhere (``ros``:
  any policy node); a callable ``(env_id) -> victim`` (e.g. the victim class) with ``act``, ``meta.provenance`` and ``close``.
- ``aril_ros.benchmarks``: modules ``aril report`` runs as ``python -m <module> key:=value ...``,
  each ending with one JSON line (``graph``: the ROS 2 graph's steps/s).

Nothing here imports an entry point until it is asked for by name.
"""
from __future__ import annotations

from importlib.metadata import entry_points

GROUPS = ("aril_ros.commands", "aril_ros.collectors", "aril_ros.victims", "aril_ros.benchmarks")


def names(group: str) -> list[str]:
    """The names registered in ``group`` (without importing them)."""
    return sorted({ep.name for ep in entry_points(group=group)})


def load(group: str, name: str):
    """The object registered as ``name`` in ``group``; a ValueError naming what is registered if none is."""
    found = [ep for ep in entry_points(group=group) if ep.name == name]
    if not found:
        registered = ", ".join(names(group)) or "nothing"
        raise ValueError(f"no {group.split('.')[-1][:-1]} named {name!r} is installed (registered: {registered}); "
                         "the ROS 2 ones come with the aril_ros_nodes package of this repository")
    return found[0].load()


def value(group: str, name: str) -> str:
    """The target an entry point names (e.g. a module for ``aril_ros.benchmarks``), without importing it."""
    found = [ep for ep in entry_points(group=group) if ep.name == name]
    if not found:
        raise ValueError(f"no {group} entry named {name!r} is installed")
    return found[0].value
