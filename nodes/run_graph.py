"""Run attacked episodes through the ROS 2 graph: ``python run_graph.py mode:=sensory [key:=value ...]``.

Starts the simulator, attacker, policy and expert nodes as processes in a ROS domain of their own,
runs the episodes in lockstep, records them to MCAP and prints per-episode figures and one JSON
summary line. ``--help`` lists the arguments. The checkout's ``run_graph.py`` installs what it needs on
first use and runs this; ``python -m aril_ros_nodes.run_graph`` runs it from the installed package.

Exit codes: 0 for a complete run, 1 for a refused argument or a failed run, 128 + the signal's number
for a run stopped by a signal (130 for Ctrl-C, 143 for SIGTERM).
"""
import json
import os
import sys

from aril_ros.args import parse_args, usage
from aril_ros_nodes.orchestrator import GraphConfig, GraphError, Orchestrator, RunInterrupted


def main(argv) -> int:
    if "-h" in argv or "--help" in argv:
        print(usage(GraphConfig, "python run_graph.py", __doc__.strip().splitlines()[0]))
        return 0
    try:
        summary = Orchestrator(parse_args(GraphConfig, argv), log=print).run()
    except (ValueError, GraphError) as err:  # bad arguments, ids, files (all ValueErrors) or a failed run
        print(f"run_graph: error: {err}", file=sys.stderr)
        return 1
    except RunInterrupted as err:  # a stop signal during the run: 130 for SIGINT, 143 for SIGTERM
        print(f"run_graph: {err}; nodes stopped, log closed as interrupted", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:  # Ctrl-C before the run began: nothing started yet
        print("run_graph: interrupted before the run began", file=sys.stderr)
        return 130
    print(json.dumps(summary))
    return 0


def run_and_exit(argv) -> None:
    """:func:`main`, then end the process at once. The run is over (nodes stopped, log closed, DDS participant
    gone): Python's own teardown of torch and the DDS libraries would keep the user waiting 1-2.5 s more on
    a loaded machine."""
    code = main(argv)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    run_and_exit(sys.argv[1:])
