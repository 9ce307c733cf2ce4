#!/usr/bin/env python3
"""Run attacked episodes through the ROS 2 graph: ``python run_graph.py mode:=sensory [key:=value ...]``.

Installs what it needs on first use, then runs :mod:`aril_ros_nodes.run_graph` (``--help`` lists the
arguments).
"""
import sys

from bootstrap import ensure_venv

if __name__ == "__main__":
    ensure_venv()
    from aril_ros_nodes.run_graph import run_and_exit

    run_and_exit(sys.argv[1:])
