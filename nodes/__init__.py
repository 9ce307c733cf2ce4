"""The ROS 2 side of aril_ros, installed as ``aril_ros_nodes``: one node per module (``simulator_node``,
``attacker_node``, ``policy_node``, ``expert_node``), the ``orchestrator`` behind ``run_graph.py`` (an outline over
``graph_config``, ``launcher`` and ``graph_client``; its recorder is the library's ``aril_ros.runlog``), ``replay``,
the ``remote_policy`` client and ``collect`` (a DAgger round through the graph). It imports the library; the
library reaches it only through the entry points in ``pyproject.toml``. The graph's benchmarks and profiler are
the checkout's (``benchmarks/graph/``), not installed with it."""
