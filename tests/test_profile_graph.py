"""profile_graph's bookkeeping: which process is which, and the CPU a process has used."""
import os
import time

from benchmarks.graph.profile_graph import CpuSampler, process_name


def test_processes_are_named_by_their_part_of_the_run():
    me = os.getpid()
    assert process_name(me, "python anything").startswith("this process")
    assert process_name(1, "python -m aril_ros_nodes.simulator_node --ros-args -p env:=Ant-v5") == "simulator"
    assert process_name(1, "python -m aril_ros_nodes.policy_node --ros-args") == "policy"
    assert process_name(1, "python -m benchmarks.graph.bare_chain --ros-args -p role:=expert -r __node:=x") == "bare expert"
    assert process_name(1, "python train.py") is None


def test_the_sampler_reads_the_cpu_this_process_uses():
    with CpuSampler() as sampler:
        time.sleep(0.15)
        before = sampler.by_name()
        started = time.process_time()
        while time.process_time() - started < 0.5:  # half a second of CPU
            pass
        time.sleep(0.25)
    used = sum(sampler.by_name().values()) - sum(before.values())
    assert 0.4 < used < 1.5


def test_a_step_costs_the_cpu_used_between_the_marks_alone():
    from benchmarks.graph.profile_graph import per_step

    def busy(seconds):
        started = time.process_time()
        while time.process_time() - started < seconds:
            pass

    def run(steps, mark):
        busy(0.3)  # start-up: outside the window
        mark()
        busy(0.5)
        mark()
        busy(0.3)  # shutting down: outside too

    figures = per_step(run, steps=100)
    assert 4.0 < sum(figures.values()) < 7.0  # 0.5 s over 100 steps: 5 ms each, start-up and shutdown left out


def test_the_graph_benchmarks_are_the_checkout_s_and_registered_for_the_report():
    import importlib.util

    from aril_ros import plugins

    for name in ("bench_graph", "bench_soak", "bare_chain", "profile_graph"):
        assert importlib.util.find_spec(f"aril_ros_nodes.{name}") is None  # not installed with the ROS package
        assert importlib.util.find_spec(f"benchmarks.graph.{name}") is not None
    assert [plugins.value("aril_ros.benchmarks", n) for n in ("graph", "soak")] == [
        "benchmarks.graph.bench_graph", "benchmarks.graph.bench_soak"]
