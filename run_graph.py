#!/usr/bin/env python3
"""Run attacked episodes through the ROS 2 graph: ``python run_graph.py mode:=sensory [key:=value ...]``.

Starts the simulator, attacker, policy and expert nodes as processes in a ROS domain of their own,
runs the episodes in lockstep, records them to MCAP and prints per-episode figures and one JSON
summary line. ``--help`` lists the arguments. Installs what it needs on first use.
"""
import json
import sys

from bootstrap import ensure_venv


def main(argv) -> int:
    from aril_ros.args import parse_args, usage
    from aril_ros_nodes.orchestrator import GraphConfig, GraphError, Orchestrator

    if "-h" in argv or "--help" in argv:
        print(usage(GraphConfig, "python run_graph.py", __doc__.strip().splitlines()[0]))
        return 0
    try:
        summary = Orchestrator(parse_args(GraphConfig, argv), log=print).run()
    except (ValueError, GraphError) as err:  # bad arguments, ids, files (all ValueErrors) or a failed run
        print(f"run_graph: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("run_graph: interrupted; nodes stopped, log closed", file=sys.stderr)
        return 130
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    ensure_venv()
    sys.exit(main(sys.argv[1:]))
