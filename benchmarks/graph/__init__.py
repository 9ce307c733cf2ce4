"""The ROS 2 graph's benchmarks and profiler, run from a checkout (not installed with ``aril_ros_nodes``):
``python -m benchmarks.graph.bench_graph`` (steps/s per mode beside the bare rclpy chain of ``bare_chain``),
``bench_soak`` (runs at once, over time) and ``profile_graph`` (CPU per step of each process). ``aril report``
runs the first two through the ``aril_ros.benchmarks`` entry points ``graph`` and ``soak``, from the checkout's
root."""
