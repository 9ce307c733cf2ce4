#!/usr/bin/env python3
"""Run attacked episodes: ``python run_graph.py mode:=sensory [key:=value ...]``.

Placeholder until the ROS 2 graph lands: it runs the same episodes on the in-process engine
(``aril eval``) and says so. Installs what it needs on first use.
"""
import sys

from bootstrap import ensure_venv

if __name__ == "__main__":
    ensure_venv()
    from aril_ros.cli import main

    print("[run_graph] the ROS 2 graph is not built yet; running the in-process engine", file=sys.stderr)
    sys.exit(main(["eval", *sys.argv[1:]]))
