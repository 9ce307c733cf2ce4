"""Sweeps as Ray tasks (aril_ros.sweep): in this process, on a local Ray, and on a two-node cluster on this machine."""
import json
import math
import operator
from pathlib import Path

import pytest

from aril_ros.provenance import cpu
from aril_ros.extras import FOXGLOVE, RAY
from aril_ros.registry import BundledFileError, adversary_path, bundled_file
from aril_ros.report.jobs import FAILURES, evaluated_on, run_jobs
from aril_ros.sweep import Kept, Produced, Shipped, connect, ensure_ray, kept_folder, run_tasks

# one pytest-xdist worker runs them all: one Ray installed once (ensure_ray), one cluster at a time
pytestmark = pytest.mark.xdist_group("ray")


def quiet(*args, **kwargs):
    pass


def where_and_what(source: Path, out: Path) -> tuple[str, str, str]:
    """A task reading one file and writing another: the node it ran on and the paths it was given."""
    import ray

    out.write_text(source.read_text().upper())
    return ray.get_runtime_context().get_node_id(), str(source), str(out)


@pytest.mark.slow
@pytest.mark.parametrize("workers", [1, 2])
def test_failures_named_by_the_caller_come_back_and_others_are_raised(workers):
    ray = connect("", workers)[0] if workers > 1 else None  # one embedded local Ray for both sweeps
    try:
        results = dict(run_tasks(math.sqrt, [(4.0,), (-1.0,), (9.0,)], workers, failures=FAILURES, log=quiet))
        # a missing cell, recorded by its own message (on Ray too: not the task's traceback)
        assert results[0] == 2.0 and results[2] == 3.0 and str(results[1]) == "math domain error"
        with pytest.raises(ZeroDivisionError) as bug:  # a bug, not a missing file: stops the sweep
            list(run_tasks(operator.truediv, [(1, 0)], workers, log=quiet))
        # on Ray the task's traceback comes with it, as its cause
        assert workers == 1 or "in _task" in str(bug.value.__cause__)
        with pytest.raises(BundledFileError) as user_error:  # a user's error is raised as the task raised it
            list(run_tasks(bundled_file, [("dagger", "Hopper-v5")], workers, log=quiet))
        assert type(user_error.value) is BundledFileError and str(user_error.value).startswith("no dagger for Hopper-v5")
        assert "\n" not in str(user_error.value)
    finally:
        if ray is not None:
            ray.shutdown()


@pytest.fixture(scope="module")
def two_nodes():
    """A Ray cluster of two nodes, one CPU each, on this machine, connected for the module's tests."""
    ray = ensure_ray()  # CI's first use installs it, as a user's first sweep does
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    cluster.add_node(num_cpus=1)
    ray.init(address=cluster.address, logging_level="ERROR", log_to_driver=False)
    yield cluster
    ray.shutdown()
    cluster.shutdown()


def two_nodes_driver() -> str:
    import ray

    return ray.get_runtime_context().get_node_id()


@pytest.mark.slow
def test_tasks_run_on_both_nodes_and_files_travel_by_content(two_nodes, tmp_path):
    sources = []
    for i in range(6):
        sources.append(tmp_path / f"in{i}.txt")
        sources[-1].write_text(f"file {i}")
    calls = [(Shipped(s), Produced(tmp_path / "out" / f"out{i}.txt")) for i, s in enumerate(sources)]
    lines = []
    results = dict(run_tasks(where_and_what, calls, address=two_nodes.address, label="files",
                             log=lambda line, **_: lines.append(line)))
    assert len({node for node, _, _ in results.values()}) == 2, "every task ran on one node"
    driver = two_nodes_driver()
    for i, (node, seen_source, seen_out) in results.items():
        # on the driver's node the task reads the driver's file (what it records of it is then what the driver named);
        # on the other node its node's copy, found by the file's digest
        assert (seen_source == str(sources[i])) == (node == driver)
        assert Path(seen_out) == tmp_path / "out" / f"out{i}.txt"  # a result naming a made file names the driver's
        assert (tmp_path / "out" / f"out{i}.txt").read_text() == f"FILE {i}"  # made files come back to the driver
    assert lines[-1].startswith("[sweep] files: 6/6 done, 0 running, 0 failed")


@pytest.mark.slow
def test_a_task_sees_relative_paths_as_the_driver_gave_them(two_nodes, tmp_path, monkeypatch):
    """What a task records of its files (a trained file's provenance) must not be a worker's scratch path."""
    monkeypatch.chdir(tmp_path)
    Path("in.txt").write_text("policy bytes")
    results = dict(run_tasks(where_and_what, [(Shipped(Path("in.txt")), Produced(Path("made/out.txt")))],
                             address=two_nodes.address, log=quiet))
    _, seen_source, seen_out = results[0]
    assert (seen_source, seen_out) == ("in.txt", "made/out.txt")
    assert Path("made/out.txt").read_text() == "POLICY BYTES"


def records_its_paths(source: Path, out: Path) -> Path:
    """A task writing, into the file it makes, the paths it was given for its files (as a trained file's
    provenance does)."""
    out.write_text(f"{source} {out}")
    return out


@pytest.mark.slow
def test_a_task_sees_files_inside_the_checkout_by_their_checkout_relative_path(two_nodes, tmp_path, monkeypatch):
    """A bundled file is named by its absolute path (aril defense-table hands the trainer one): the file the task
    makes must record it as provenance.stamp does in one process, not as a worker's scratch path, and still land
    at the driver's absolute path, wherever the driver runs from."""
    import aril_ros.provenance

    checkout = tmp_path / "checkout"
    monkeypatch.setattr(aril_ros.provenance, "CHECKOUT", checkout)
    (checkout / "data").mkdir(parents=True)
    (checkout / "data" / "victim.pt").write_text("victim bytes")
    monkeypatch.chdir(tmp_path)  # not the checkout
    call = (Shipped(checkout / "data" / "victim.pt"), Produced(checkout / "data" / "made" / "adversary.pt"))
    results = dict(run_tasks(records_its_paths, [call], address=two_nodes.address, log=quiet))
    assert results[0] == checkout / "data" / "made" / "adversary.pt"  # a result naming a made file names the driver's
    assert results[0].read_text() == "data/victim.pt data/made/adversary.pt"
    assert not (tmp_path / "data").exists()  # written where the driver named it, not relative to its working folder


def count_then_fail(folder: Path, fail: bool) -> tuple[str, int]:
    """A training that keeps one round per call in ``folder`` and is cut off when ``fail``: the path it was
    given and the rounds finished by now."""
    rounds = len(list(folder.glob("round-*"))) + 1
    (folder / f"round-{rounds}").write_text("done")
    if fail:
        raise RuntimeError("interrupted")
    return str(folder), rounds


@pytest.mark.slow
def test_a_kept_folder_outlives_its_task_so_the_same_call_resumes(two_nodes, tmp_path, monkeypatch):
    """A training's run directory (``Kept``): on the driver's machine, the driver's folder, reached through the
    path the call gave (so provenance records no scratch path), still there after the task failed."""
    monkeypatch.chdir(tmp_path)
    call = (Kept(Path("learners/aril-seed1")),)
    first = dict(run_tasks(count_then_fail, [(*call, True)], address=two_nodes.address, failures=(RuntimeError,),
                           log=quiet))
    assert isinstance(first[0], RuntimeError) and (tmp_path / "learners/aril-seed1/round-1").exists()
    again = dict(run_tasks(count_then_fail, [(*call, False)], address=two_nodes.address, log=quiet))
    assert again[0] == ("learners/aril-seed1", 2)  # resumed after round 1, seen by the relative path given
    # on a node of another machine: a folder of that node's, the same for the same call, never the driver's path
    elsewhere = Kept(Path("learners/aril-seed1"), host="another-node")
    assert kept_folder(elsewhere) == kept_folder(Kept(Path("learners/aril-seed1"), host="another-node"))
    assert not kept_folder(elsewhere).is_relative_to(tmp_path)
    assert kept_folder(call[0]) == tmp_path / "learners/aril-seed1"


@pytest.mark.slow
def test_an_evaluation_sweep_on_two_nodes_is_bit_identical_to_one_process(two_nodes, tmp_path):
    env, mode = "Swimmer-v5", "sensory"
    policy, adversary = bundled_file("dagger", env), adversary_path(env, mode, "dagger")
    jobs = [{"env": env, "policy": str(policy), "mode": "clean" if attack == "none" else mode, "attack": attack,
             "eps": 0.3, "attack_file": str(adversary) if attack == "aril_a" else "", "rescale": attack == "aril_a",
             "episodes": 2, "seed": 3000 + i, "horizon": 40}
            for i, attack in enumerate(["none", "random", "fgsm", "aril_a", "random", "none"])]
    on_cluster, counts, _ = run_jobs(jobs, tmp_path / "cluster", 2, two_nodes.address, False, quiet)
    in_process, _, _ = run_jobs(jobs, tmp_path / "serial", 1, "", False, quiet)
    assert counts == {"run": 6, "cached": 0}
    assert on_cluster == in_process
    # the cache is the driver's: the same sweep again runs nothing
    again, counts, _ = run_jobs(jobs, tmp_path / "cluster", 2, two_nodes.address, False, quiet)
    assert again == on_cluster and counts == {"run": 0, "cached": 6}


def test_each_extra_is_what_its_first_use_installs():
    import tomllib

    pyproject = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    extras = pyproject["project"]["optional-dependencies"]
    assert extras["cluster"] == [RAY] and extras["live"] == [FOXGLOVE]
    assert FOXGLOVE in extras["test"]  # the live view's test needs it, and CI installs the test extra


def test_a_task_runs_as_many_physics_threads_as_it_has_cpus(monkeypatch):
    import os

    from aril_ros.envs import physics_threads

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert physics_threads() == len(os.sched_getaffinity(0))
    monkeypatch.setenv("OMP_NUM_THREADS", "1")  # what Ray sets in a task of one CPU
    assert physics_threads() == 1


@pytest.mark.slow
def test_a_table_on_two_nodes_is_the_table_of_one_process(two_nodes, tmp_path, make_policy):
    """The tables' evaluations are sweep tasks too (calibrate-eps here): a policy file of the caller's travels."""
    from aril_ros.experiments import CalibrationConfig, calibrate_eps
    from aril_ros.policy import save_policy

    victim = save_policy(make_policy("Swimmer-v5", seed=1), tmp_path / "victim.pt")
    common = dict(envs="Swimmer-v5", modes="sensory,physical", policy=str(victim), grid="0.01,0.3", episodes=2,
                  horizon=30)
    rows = [calibrate_eps(CalibrationConfig(**common, out=str(tmp_path / name), **how), log=quiet)["rows"]
            for name, how in (("one", {"workers": 1}), ("two", {"address": two_nodes.address}))]
    assert [r["sweep"] for r in rows[1]] == [r["sweep"] for r in rows[0]]


@pytest.mark.slow
def test_a_scan_on_two_nodes_trains_and_ranks_as_one_process(two_nodes, tmp_path):
    """Trainings are tasks too: an adversary trained on a worker is the one trained here, bit for bit in effect."""
    from aril_ros.scan import ScanConfig, scan_adversary

    common = dict(env="Swimmer-v5", mode="sensory", grid="lr=0.001,0.0003 n_envs=4 rollout=64", steps=256,
                  episodes=2, horizon=30)
    ranked = [[(p["grid"], p["returns"]) for p in scan_adversary(ScanConfig(**common, out=str(tmp_path / name), **how),
                                                                 log=quiet)["points"]]
              for name, how in (("one", {"workers": 1}), ("two", {"address": two_nodes.address}))]
    assert ranked[1] == ranked[0]


@pytest.mark.slow
def test_names_of_the_users_data_travel_as_their_files(two_nodes, tmp_path, monkeypatch, make_policy):
    """An onboarded env's ``dagger`` and ``expert`` live in the driver's $ARIL_DATA (here relative to the driver's
    folder), which the cluster's nodes do not have: a sweep sends them as files, and gives what one process gives."""
    from aril_ros.evaluation import evaluate_all
    from aril_ros.policy import save_policy
    from aril_ros.registry import user_path

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("ARIL_DATA", "my-data")
    for name, seed in (("expert", 1), ("dagger", 2)):
        path = user_path(name, "Hopper-v5")
        path.parent.mkdir(parents=True, exist_ok=True)
        save_policy(make_policy("Hopper-v5", seed=seed), path)
    jobs = [{"env": "Hopper-v5", "policy": "dagger", "expert": "expert", "mode": mode, "attack": attack, "eps": 0.01,
             "episodes": 2, "seed": 3000, "horizon": 30} for mode, attack in (("clean", "none"), ("sensory", "random"))]
    on_cluster = evaluate_all(jobs, 2, two_nodes.address, quiet)
    in_process = evaluate_all(jobs, 1, "", quiet)
    assert [r["returns"] for r in on_cluster] == [r["returns"] for r in in_process]
    assert [r["mean_expert_loss"] for r in on_cluster] == [r["mean_expert_loss"] for r in in_process]


@pytest.mark.slow
def test_a_killed_sweep_resumes_with_what_had_finished(two_nodes, tmp_path):
    """Ctrl-C on the driver of a sweep on a local Ray, then the same sweep again: the finished tasks are not rerun.
    A cluster runs on this machine meanwhile (``two_nodes``): the driver's embedded Ray must be its own, not join it."""
    import os
    import signal
    import subprocess
    import sys
    import time

    # long enough that the rest cannot finish while the Ctrl-C reaches a driver on a loaded machine
    jobs = [{"env": "Swimmer-v5", "policy": str(bundled_file("dagger", "Swimmer-v5")), "mode": "sensory",
             "attack": "random", "eps": 0.3, "episodes": 4, "seed": 3000 + 4 * i, "horizon": 1000} for i in range(12)]
    (tmp_path / "jobs.json").write_text(json.dumps(jobs))
    # Ctrl-C as at a terminal: a suite started in the background by a shell inherits SIGINT ignored (twice, started
    # so on a loaded machine, the driver ran every job to the end)
    script = ("import json, signal, sys; from pathlib import Path; from aril_ros.report.jobs import run_jobs; "
              "signal.signal(signal.SIGINT, signal.default_int_handler); "
              "run_jobs(json.loads(Path(sys.argv[1]).read_text()), Path(sys.argv[2]), 2, '', False, print)")
    cache = tmp_path / "cache"
    driver = subprocess.Popen([sys.executable, "-c", script, str(tmp_path / "jobs.json"), str(cache)],
                              start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 180
        while len(list(cache.glob("*.json"))) < 1 and driver.poll() is None and time.monotonic() < deadline:
            time.sleep(0.2)
    finally:
        if driver.poll() is None:
            os.killpg(driver.pid, signal.SIGINT)  # the driver and the Ray it started: one session
        driver.wait(timeout=60)
        time.sleep(2)
        subprocess.run(["pkill", "-KILL", "-s", str(driver.pid)], check=False)
    finished = len(list(cache.glob("*.json")))
    assert 1 <= finished < len(jobs), "the sweep was to be stopped part way"
    returns, counts, runs = run_jobs(jobs, cache, 1, "", False, quiet)
    assert counts == {"run": len(jobs) - finished, "cached": finished}
    assert all(len(r) == 4 for r in returns)
    # the cached ones kept the time they took and the CPU they ran on
    assert len(runs) == len(jobs) and all(run["seconds"] > 0 for run in runs)
    assert evaluated_on(runs) == {cpu(): len(jobs)}
    assert evaluated_on([*runs, {"seconds": 1.0}])["CPU not recorded"] == 1


@pytest.mark.slow
def test_the_cache_knows_files_by_content_so_a_committed_cache_serves_another_checkout(tmp_path):
    import shutil

    here, there = tmp_path / "here", tmp_path / "elsewhere" / "checkout"
    for checkout in (here, there):
        checkout.mkdir(parents=True)
        shutil.copy(bundled_file("dagger", "Swimmer-v5"), checkout / "Swimmer-v5.pt")
    job = {"env": "Swimmer-v5", "mode": "sensory", "attack": "random", "eps": 0.3, "episodes": 1, "seed": 3000,
           "horizon": 40}
    first, counts, _ = run_jobs([{**job, "policy": str(here / "Swimmer-v5.pt")}], tmp_path / "cache", 1, "", False,
                                quiet)
    assert counts == {"run": 1, "cached": 0}
    again, counts, _ = run_jobs([{**job, "policy": str(there / "Swimmer-v5.pt")}], tmp_path / "cache", 1, "", False,
                                quiet)
    assert counts == {"run": 0, "cached": 1} and again == first
    # another file at the same path is another evaluation
    shutil.copy(bundled_file("dart", "Swimmer-v5"), there / "Swimmer-v5.pt")
    _, counts, _ = run_jobs([{**job, "policy": str(there / "Swimmer-v5.pt")}], tmp_path / "cache", 1, "", False,
                            quiet)
    assert counts == {"run": 1, "cached": 0}
