#!/usr/bin/env python3
"""Run attacked episodes through the ROS 2 graph: ``python run_graph.py mode:=sensory [key:=value ...]``.

Installs what it needs on first use, then runs :mod:`aril_ros_nodes.run_graph` (``--help`` lists the
arguments).
"""
import signal
import sys

from bootstrap import ensure_venv, exit_on_interrupt

if __name__ == "__main__":
    exit_on_interrupt("run_graph: interrupted before the run began")  # first: the imports below take seconds
    ensure_venv()
    from aril_ros_nodes.run_graph import run_and_exit

    signal.signal(signal.SIGINT, signal.default_int_handler)  # the run answers Ctrl-C itself from here on
    run_and_exit(sys.argv[1:])
