"""Benchmarks of the library, each a module run as ``python -m aril_ros.benchmarks.<name> key:=value ...``
that prints a table and ends with one JSON line of its figures:

- ``engine``: raw ``env.step`` vs the in-process engine (clean, sensory, physical), steps/s.
- ``adversary``: ARIL-A's trainer vs stable-baselines3 PPO, env steps/s.

They are registered in the ``aril_ros.benchmarks`` entry points (with the ROS side's ``graph``), through
which ``aril report`` finds and runs them (:mod:`aril_ros.report.perf`).
"""
