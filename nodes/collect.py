"""A DAgger round through the ROS 2 graph: the ``aril_ros.collectors`` entry point ``graph``.

``aril train-learner source:=graph`` hands :func:`collect_round` a :class:`aril_ros.collectors.RoundSpec`;
the round runs here, in the caller's process, through the :class:`Orchestrator` (the nodes are its
child processes, as with ``run_graph.py``), and its run log is what the library reads back: the steps, and each
episode's figures as the recorder took them while the round ran (the log's end record,
:attr:`aril_ros.runlog.reader.RunLog.episode_stats`).
"""
from __future__ import annotations

import sys
from pathlib import Path

from aril_ros_nodes.orchestrator import GraphConfig, GraphError, Orchestrator


def _to_stderr(*args, **kwargs) -> None:
    print(*args, **{**kwargs, "file": sys.stderr})


def collect_round(spec, log=_to_stderr) -> Path:
    """Run the round ``spec`` (a :class:`aril_ros.collectors.RoundSpec`) through the graph, recorded to
    ``spec.record``; return that path. The orchestrator's progress goes to ``log`` (stderr by
    default); a failed run raises a RuntimeError naming the round's log and the cause."""
    cfg = GraphConfig(env=spec.env, mode=spec.mode, attack=spec.attack, eps=spec.eps, policy=spec.policy,
                      expert=spec.expert, attack_file=spec.attack_file, episodes=spec.episodes, seed=spec.seed,
                      record=str(spec.record), horizon=spec.horizon, domain=spec.domain, rescale=spec.rescale,
                      k=spec.k, samples=spec.samples, search=spec.search, delay=spec.delay, drop=spec.drop,
                      action_delay=spec.action_delay, timing=spec.timing,
                      timing_file=spec.timing_file)
    try:
        Orchestrator(cfg, log=log).run()
    except (ValueError, GraphError) as err:  # bad files or settings, or a node that died or stalled
        raise RuntimeError(f"the graph run for {Path(spec.record).name} ({spec.record}) failed: {err}") from err
    return Path(spec.record)
