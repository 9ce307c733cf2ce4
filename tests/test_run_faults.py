"""How a run ends when it does not end well: arguments refused before any node starts, a stop signal's exit
code, a node's death named by its signal and its log's real last error, and every abnormal end closing the
log as interrupted with the reason. Each graph run is a short Swimmer run in a domain of its own."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from aril_ros.runlog import read_run
from aril_ros_nodes.launcher import last_error_line
from aril_ros_nodes.orchestrator import GraphConfig, Orchestrator
from tests.conftest import ROOT, free_domain, policy_files, processes_in_domain, run_graph

EPS_RANGE = "allowed 0 < eps <= 1.0"
DOMAIN_RANGE = "is not an allowed ROS domain id: auto, 0-101 or 215-232"


@pytest.mark.parametrize("args, message", [
    ({"episodes": 0}, "episodes:=0 is out of range: allowed 1..100000"),
    ({"episodes": -1}, "episodes:=-1 is out of range: allowed 1..100000"),
    ({"eps": -0.01}, f"eps:=-0.01 is out of range: {EPS_RANGE}"),
    ({"eps": 1e9}, f"eps:=1000000000.0 is out of range: {EPS_RANGE}"),
    ({"eps": float("nan")}, f"eps:=nan is out of range: {EPS_RANGE}"),
    ({"domain": "300"}, f"domain:=300 {DOMAIN_RANGE}"),
    ({"domain": "150"}, f"domain:=150 {DOMAIN_RANGE}"),
    ({"domain": "abc"}, f"domain:=abc {DOMAIN_RANGE}"),
    ({"horizon": 0}, "horizon:=0 is out of range: allowed 1..1000000"),
    ({"k": -1}, "k:=-1 is out of range: allowed 0..1000"),
    ({"seed": -1}, "seed:=-1 is out of range: allowed 0..2147483647"),
    ({"step_timeout": 0.0}, "step_timeout:=0.0 is out of range: allowed 1.0..3600.0"),
    ({"connect_timeout": float("inf")}, "connect_timeout:=inf is out of range: allowed 1.0..3600.0"),
    ({"render": True, "render_every": 0}, "render_every:=0 is out of range: allowed >= 1"),
    ({"render": True, "render_size": "320"}, "render_size:=320 is not a frame size: <width>x<height>"),
    ({"attack": "random", "search": 4}, "search:=4 is used by attack:=aril_a only, got attack:=random"),
    ({"attack_file": "adversary.pt"}, "attack_file:=adversary.pt is used by attack:=aril_a and attack:=transfer only"),
    ({"attack": "spsa", "rescale": True}, "rescale:=True is used by attack:=aril_a only, got attack:=spsa"),
    ({"samples": 4}, "samples:=4 is used by attack:=spsa only, got attack:=aril_a"),  # the default against DAgger
    ({"attack": "transfer"}, "attack:=transfer runs FGSM^k on a surrogate of the policy: pass its file as "
                             "attack_file:="),
    ({"attack": "transfer", "attack_file": "missing.pt"}, "missing.pt: no such policy file"),
    ({"attack": "transfer", "attack_file": "aril_ros/data/adversary/Swimmer-v5-sensory.pt"},
     "aril_ros/data/adversary/Swimmer-v5-sensory.pt: not an aril_ros policy file"),  # an adversary is no surrogate
    ({"mode": "sensory", "attack": "aril_a", "eps": 0.5}, "aril_ros/data/adversary/Swimmer-v5-sensory.pt was trained "
                                                           "with eps=0.3, not eps=0.5 (rescale:=true scales it)"),
])
def test_every_argument_is_checked_before_anything_starts(args, message):
    """The orchestrator's constructor refuses it (nodes start only in ``run``), for an in-process caller's
    config as for ``run_graph.py``'s (``parse_args`` checks the ranges too)."""
    with pytest.raises(ValueError) as refused:
        Orchestrator(GraphConfig(env="Swimmer-v5", record="off", **args))
    assert message in str(refused.value)


@pytest.mark.slow
def test_run_graph_refuses_a_bad_argument_with_a_message_and_starts_nothing():
    domain = free_domain()
    out = run_graph("episodes:=0", domain=domain, timeout=120, process=True)  # the script's exit code and output
    assert out.returncode == 1
    assert out.stderr.strip() == "run_graph: error: episodes:=0 is out of range: allowed 1..100000"
    handlers = [signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)]
    here = run_graph("episodes:=0", domain=domain)  # the suite's in-process runs give what the script gives
    assert (here.returncode, here.stdout, here.stderr) == (out.returncode, out.stdout, out.stderr)
    assert [signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)] == handlers


def test_transfer_without_its_surrogate_file_is_one_line_and_starts_nothing():
    out = run_graph("attack:=transfer")
    assert out.returncode == 1
    assert out.stderr.strip() == ("run_graph: error: attack:=transfer runs FGSM^k on a surrogate of the policy: pass "
                                  "its file as attack_file:= (aril fit-surrogate)")


def test_a_reader_that_leaves_before_the_help_is_written_gets_no_traceback():
    """``python run_graph.py --help | head``: the pipe is closed before the help is written."""
    proc = subprocess.Popen([sys.executable, str(ROOT / "run_graph.py"), "--help"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()
    stderr = proc.stderr.read().decode()
    assert (proc.wait(60), stderr) == (1, "")  # Python's own exit code on a broken pipe, without its traceback


def test_a_node_log_s_last_error_is_an_error_line_or_none(tmp_path):
    log = tmp_path / "policy.log"
    log.write_text("[INFO] [1.0] [policy]: waiting for 2 subscribers on action\n")
    assert last_error_line(log) is None  # a start-up INFO line is not why a node ended
    log.write_text("[WARN] [1.0] [simulator]: slow step\n/x/envs.py:40: RuntimeWarning: MuJoCo: unstable\n"
                   "[INFO] [2.0] [simulator]: still here\n")
    assert last_error_line(log) == "/x/envs.py:40: RuntimeWarning: MuJoCo: unstable"
    log.write_text("Traceback (most recent call last):\n  File \"x.py\", line 1\nValueError: bad action\n"
                   "[simulator] FATAL: ValueError: bad action\n[WARN] [3.0] [simulator]: later warning\n")
    assert last_error_line(log) == "[simulator] FATAL: ValueError: bad action"  # an error outranks a warning


def start_run(tmp_path, domain):
    """A long Swimmer run, returned once its first episode is done (so every node is up and stepping)."""
    policy, expert = policy_files(tmp_path, "Swimmer-v5")
    log = tmp_path / "run.mcap"
    proc = subprocess.Popen([sys.executable, str(ROOT / "run_graph.py"), "env:=Swimmer-v5", f"policy:={policy}",
                             f"expert:={expert}", "episodes:=10000", "horizon:=20", f"record:={log}",
                             f"domain:={domain}"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:
        if line.startswith("episode"):
            return proc, log
    raise AssertionError(f"the run ended before its first episode (exit code {proc.wait()})")


def stop_run(proc) -> str:
    """The rest of the run's stderr once it has ended; it is killed if it has not within 30 s."""
    try:
        return proc.communicate(timeout=30)[1]
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.communicate()[1] + "\n(killed: no exit within 30 s)"


@pytest.mark.slow
@pytest.mark.parametrize("signum, exit_code", [(signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_a_stop_signal_exits_with_its_code_and_closes_the_log_as_interrupted(signum, exit_code, tmp_path):
    domain = free_domain()
    proc, log = start_run(tmp_path, domain)
    try:
        proc.send_signal(signum)
        err = stop_run(proc)
    finally:
        proc.kill()
    name = signal.Signals(signum).name
    assert proc.returncode == exit_code, err
    assert f"run_graph: interrupted by {name}" in err
    assert processes_in_domain(domain) == []
    run = read_run(log, allow_interrupted=True)
    assert run.end["interrupted"] is True and run.end["reason"] == f"interrupted by {name}"
    assert len(run.tags) >= 20  # the complete steps, the first episode's at least


def pid_of_node(domain: int, name: str) -> int:
    for process in processes_in_domain(domain):
        pid, cmdline = process.split(": ", 1)
        if f"aril_ros_nodes.{name}_node" in cmdline:
            return int(pid)
    raise AssertionError(f"no {name} node in domain {domain}")


@pytest.mark.slow
def test_a_killed_node_is_named_with_its_signal_and_the_log_closed_as_interrupted(tmp_path):
    domain = free_domain()
    proc, log = start_run(tmp_path, domain)
    try:
        os.kill(pid_of_node(domain, "policy"), signal.SIGKILL)
        err = stop_run(proc)
    finally:
        proc.kill()
    assert proc.returncode == 1, err
    death = re.search(r"node 'policy' was killed by SIGKILL; its log has no error line \(full log: (\S+)\)", err)
    assert death, err
    assert Path(death[1]).name == "policy.log" and Path(death[1]).is_file()
    assert processes_in_domain(domain) == []
    run = read_run(log, allow_interrupted=True)
    assert run.end["interrupted"] is True and "node 'policy' was killed by SIGKILL" in run.end["reason"]


@pytest.mark.slow
def test_any_exception_closes_the_log_as_interrupted_with_its_reason(tmp_path, monkeypatch):
    """A fault of the orchestrator's own (here a bug planted in episode 1) is not a complete run."""

    class PlantedBug(Exception):
        pass

    run_episode = Orchestrator.run_episode

    def failing_in_episode_1(self, ros, recorder, episode):
        if episode == 1:
            raise PlantedBug("episode 1 went wrong")
        run_episode(self, ros, recorder, episode)

    monkeypatch.setattr(Orchestrator, "run_episode", failing_in_episode_1)
    policy, expert = policy_files(tmp_path, "Swimmer-v5")
    log, domain = tmp_path / "run.mcap", free_domain()
    orchestrator = Orchestrator(GraphConfig(env="Swimmer-v5", policy=str(policy), expert=str(expert), episodes=3,
                                            horizon=20, record=str(log), domain=str(domain)),
                                log=lambda *a, **k: None)
    with pytest.raises(PlantedBug):
        orchestrator.run()
    assert processes_in_domain(domain) == []
    run = read_run(log, allow_interrupted=True)
    assert run.end["interrupted"] is True
    assert run.end["reason"] == "the orchestrator failed: PlantedBug: episode 1 went wrong"
    assert len(run.tags) == 20 and run.end["episodes_completed"] == 1
