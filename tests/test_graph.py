"""Real ROS 2 graphs: separate processes, real DDS, one isolated domain per run. The nodes run from the
installed package (aril_ros_nodes), never from the checkout's folder."""
from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from aril_ros.attacks import make_attack
from aril_ros.envs import MujocoSim, layout_of
from aril_ros.policy import load_policy, save_policy
from aril_ros.rollout import RolloutEngine
from aril_ros.runlog import RunLogError, read_run, recover
from tests.conftest import (ROOT, assert_same_steps, free_domain, policy_files, processes_in_domain, random_policy,
                            ros_env, run_graph, run_with_external, simulator_and_prober, summary_of)


@pytest.mark.slow
@pytest.mark.parametrize("mode, env_id, attack", [("clean", "Swimmer-v5", "none"),
                                                  ("sensory", "HalfCheetah-v5", "random"),
                                                  ("physical", "Ant-v5", "random"),
                                                  ("physical", "HalfCheetah-v5", "fgsm_k"),
                                                  ("sensory", "Swimmer-v5", "aril_a"),
                                                  ("physical", "Swimmer-v5", "directed"),
                                                  ("sensory", "HalfCheetah-v5", "transfer")])
def test_graph_gives_the_same_trajectory_as_the_engine(mode, env_id, attack, tmp_path):
    """directed: aril_a with a directed adversary, whose actor asks the policy node about 2 points per entry."""
    from aril_ros.adversary import AdversaryConfig, train_adversary

    policy, expert = policy_files(tmp_path, env_id)
    adversary, directed = None, attack == "directed"
    if attack in ("aril_a", "directed"):
        attack = "aril_a"
        adversary = train_adversary(AdversaryConfig(env=env_id, mode=mode, eps=0.1, victim=str(policy),
                                                    expert=str(expert), steps=0, out=str(tmp_path / "adversary.pt"),
                                                    policy="directed" if directed else "categorical"),
                                    log=lambda *a, **k: None)
    if attack == "transfer":  # a surrogate is a policy file: any stands in for one fitted to the policy's answers
        adversary = save_policy(random_policy(env_id, seed=3), tmp_path / "surrogate.pt")
    log = tmp_path / "run.mcap"
    summary = summary_of(run_graph(f"mode:={mode}", f"env:={env_id}", f"policy:={policy}", f"expert:={expert}",
                                   f"attack:={attack}", "eps:=0.1", "k:=3", "episodes:=2", "horizon:=80", "seed:=4",
                                   f"record:={log}", *([f"attack_file:={adversary}"] if adversary else [])))
    victim = load_policy(policy)
    engine = RolloutEngine(env_id, victim, load_policy(expert),
                           make_attack(attack, layout_of(env_id), 0.1 if attack != "none" else 0, victim=victim,
                                       expert=load_policy(expert),
                                       steps=3 if attack in ("fgsm_k", "transfer") else None,
                                       adversary=adversary and str(adversary), mode=mode), mode,
                           n_envs=2, horizon=80)
    traj = engine.rollout(2, seed=4)
    run = read_run(log)
    assert_same_steps(run, traj)
    assert summary["steps"] == traj.length.sum() == len(run.tags)
    assert summary["mean_return"] == pytest.approx(traj.returns.mean(), abs=1e-3)
    assert summary["mean_expert_loss"] == pytest.approx(traj.mean_expert_loss, abs=1e-6)
    assert (summary["mode"], summary["env"], summary["attack"], summary["eps"], summary["episodes"],
            summary["record"]) == (mode, env_id, attack, 0.1 if attack != "none" else 0.0, 2, str(log))
    assert summary["steps_per_s"] > 0
    assert run.metadata["env"] == env_id and run.metadata["mode"] == mode
    assert run.metadata["expert_provenance"] == {"made_by": "tests"}


RECORDED_RUN = ("mode:=sensory", "episodes:=2", "horizon:=40")


@pytest.fixture(scope="module")
def recorded_files(tmp_path_factory):
    """One recorded sensory run, shared by the log tests: (log, policy file, expert file, summary)."""
    tmp = tmp_path_factory.mktemp("recorded")
    policy, expert = policy_files(tmp, "HalfCheetah-v5")
    log = tmp / "sensory.mcap"
    summary = summary_of(run_graph(*RECORDED_RUN, f"policy:={policy}", f"expert:={expert}", f"record:={log}"))
    return log, policy, expert, summary


@pytest.fixture
def recorded(recorded_files):
    return recorded_files[0]


@pytest.mark.slow
def test_recording_does_not_change_the_run(recorded_files):
    _, policy, expert, with_log = recorded_files
    without = summary_of(run_graph(*RECORDED_RUN, f"policy:={policy}", f"expert:={expert}", "record:=off"))
    assert without["record"] is None
    for key in ("mean_return", "std_return", "mean_expert_loss", "max_abs_delta", "steps"):
        assert without[key] == with_log[key], key


@pytest.mark.slow
def test_log_reads_step_by_step_with_rosbags(recorded):
    from rosbags.highlevel import AnyReader

    ours = read_run(recorded)
    seen = {}
    last_time = -1
    with AnyReader([recorded]) as reader:
        topics = {c.topic: c for c in reader.connections}
        assert set(topics) == {"/clock", "/sim/state", "/sim/physics_state", "/sim/reward", "/observation",
                               "/attack/perturbation", "/action", "/expert/action"}
        assert topics["/sim/state"].msgtype == "sensor_msgs/msg/JointState"
        qos = topics["/action"].ext.offered_qos_profiles[0]
        assert (qos.reliability.name, qos.history.name, qos.durability.name) == ("RELIABLE", "KEEP_ALL", "VOLATILE")
        for conn, timestamp, raw in reader.messages():
            assert timestamp >= last_time  # monotonic log times
            last_time = timestamp
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic != "/clock":
                seen[(msg.header.frame_id, conn.topic)] = msg
    for i, tag in enumerate(ours.tags):
        np.testing.assert_array_equal(seen[(str(tag), "/sim/state")].position, ours.true_obs[i])
        np.testing.assert_array_equal(seen[(str(tag), "/observation")].position, ours.obs[i])
        np.testing.assert_array_equal(seen[(str(tag), "/expert/action")].effort, ours.expert_action[i])
        np.testing.assert_array_equal(seen[(str(tag), "/sim/reward")].position[0], ours.reward[i])
    assert len(seen) == 7 * len(ours.tags)


@pytest.mark.slow
def test_dataset_loader_and_its_refusals(recorded, tmp_path):
    from mcap.writer import Writer

    from aril_ros.dataset import load_dagger_dataset

    data = load_dagger_dataset([recorded, recorded])
    run = read_run(recorded)
    assert len(data) == 2 * len(run.tags)
    np.testing.assert_array_equal(data.obs[: len(run.tags)], run.obs)
    np.testing.assert_array_equal(data.expert_action[len(run.tags):], run.expert_action)
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(recorded.read_bytes()[:-3000])
    with pytest.raises(RunLogError, match="truncated|cut short"):
        load_dagger_dataset([recorded, truncated])
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="someone else")
        writer.finish()
    with pytest.raises(RunLogError, match="not an aril_ros run log"):
        load_dagger_dataset(foreign)
    text = tmp_path / "notes.mcap"
    text.write_text("hello")
    with pytest.raises(RunLogError, match="not an MCAP file"):
        load_dagger_dataset(text)
    with pytest.raises(RunLogError, match="different envs"):
        load_dagger_dataset(recorded, env_id="Ant-v5")


@pytest.mark.slow
def test_replay_republishes_the_log_byte_for_byte(recorded):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState

    from aril_ros_nodes.common import STEP_QOS

    domain = free_domain()
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    node = rclpy.create_node("listener", context=context)
    got = []
    node.create_subscription(JointState, "/sim/state", got.append, STEP_QOS, raw=True)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    player = subprocess.Popen([sys.executable, "-m", "aril_ros", "replay", f"file:={recorded}", "rate:=0",
                               "wait_for_subscribers:=1"], env=ros_env(domain), cwd=ROOT,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        while player.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        for _ in range(20):
            executor.spin_once(timeout_sec=0.05)
    finally:
        player.kill()
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
    assert player.returncode == 0, player.stderr.read()
    from mcap.reader import make_reader

    with open(recorded, "rb") as f:
        recorded_states = [m.data for _, c, m in make_reader(f).iter_messages(topics=["/sim/state"])]
    assert got == recorded_states


@pytest.mark.slow
def test_the_ros_side_registers_its_command_collector_victim_and_benchmark(capsys):
    from aril_ros import plugins
    from aril_ros.cli import main
    from aril_ros_nodes import collect, remote_policy, replay

    assert plugins.load("aril_ros.commands", "replay") is replay.COMMAND
    assert replay.COMMAND.config is replay.ReplayConfig and replay.COMMAND.run is replay.replay
    assert plugins.load("aril_ros.collectors", "graph") is collect.collect_round
    assert plugins.load("aril_ros.victims", "ros") is remote_policy.RemotePolicy
    assert main(["replay", "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: aril replay") and "file:=" in out and "rate:=" in out
    bench = subprocess.run([sys.executable, "-m", plugins.value("aril_ros.benchmarks", "graph"), "--help"],
                           capture_output=True, text=True, timeout=120, cwd=ROOT)  # a module of the checkout
    assert bench.returncode == 0 and "python -m benchmarks.graph.bench_graph" in bench.stdout, bench.stderr


def child_processes() -> list[int]:
    """PIDs whose parent is this (test) process."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            if entry.name.isdigit() and int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1]) == os.getpid():
                found.append(int(entry.name))
        except (OSError, IndexError, ValueError):
            continue
    return found


def test_a_dagger_round_runs_through_the_graph_in_process(tmp_path):
    """train-learner source:=graph: the collector runs the round in the caller's process (no script by
    path) and leaves its log, which holds the engine's trajectory; a failed round names its log."""
    from aril_ros import plugins
    from aril_ros.collectors import RoundSpec

    env_id = "Hopper-v5"  # a random policy falls within 20 steps: the default horizon costs nothing
    policy, expert = policy_files(tmp_path, env_id)
    domain_before = os.environ["ROS_DOMAIN_ID"]
    spec = RoundSpec(env=env_id, mode="physical", attack="random", eps=0.05, policy=str(policy), expert=str(expert),
                     attack_file="", episodes=2, seed=7, record=tmp_path / "round-1.mcap")
    assert plugins.load("aril_ros.collectors", "graph")(spec) == spec.record
    assert child_processes() == [] and os.environ["ROS_DOMAIN_ID"] == domain_before
    run = read_run(spec.record)
    victim, labeller = load_policy(policy), load_policy(expert)
    traj = RolloutEngine(env_id, victim, labeller, make_attack("random", layout_of(env_id), 0.05), "physical",
                         n_envs=2).rollout(2, seed=7)
    assert run.metadata["seed"] == 7 and run.metadata["episodes"] == 2 and run.end["episodes_completed"] == 2
    assert_same_steps(run, traj)
    assert (traj.length < 100).all()
    broken = dataclasses.replace(spec, policy=str(tmp_path / "missing.pt"), record=tmp_path / "round-2.mcap")
    with pytest.raises(RuntimeError, match=r"round-2\.mcap.*missing\.pt: no such policy file"):
        plugins.load("aril_ros.collectors", "graph")(broken)


@pytest.mark.slow
def test_an_external_policy_node_is_swapped_in_and_attacked(tmp_path):
    summary = summary_of(run_with_external("good", tmp_path))
    run = read_run(tmp_path / "run.mcap")
    assert summary["steps"] == len(run.tags) == 50 and summary["policy"] == "external"
    np.testing.assert_array_equal(run.action, np.tanh(0.5 * run.obs[:, :6]))  # it acted on what it saw
    assert np.abs(run.obs - run.true_obs).max() > 0  # ... which was attacked
    assert run.metadata["policy_provenance"] == "external"


@pytest.mark.slow
@pytest.mark.parametrize("behaviour, message", [
    ("short", "node 'simulator' exited with code 1: .*action for step 0/0 has 1 values, HalfCheetah-v5 takes 6"),
    ("nan", "node 'simulator' exited with code 1: .*action for step 0/0 is not finite"),
    ("silent", r"step 0/0 made no progress for 4 s: waiting for action \(policy\).*external policy"),
    ("dies", r"step 0/5 made no progress for 4 s: waiting for action \(policy\).*external policy"),
])
def test_bad_policies_stop_the_graph_with_a_clear_error_and_an_intact_log(behaviour, message, tmp_path):
    out = run_with_external(behaviour, tmp_path)
    assert out.returncode == 1
    assert __import__("re").search(message, out.stderr), out.stderr
    run = read_run(tmp_path / "run.mcap", allow_interrupted=True)  # readable, with the complete steps
    assert len(run.tags) == (5 if behaviour == "dies" else 0)
    with pytest.raises(RunLogError, match="interrupted"):
        read_run(tmp_path / "run.mcap")


@pytest.mark.slow
@pytest.mark.parametrize("args, message", [
    (("attack:=aril_a", "attack_file:=missing.pt"), "missing.pt: no such adversary file"),
    (("attack:=fgsm", "policy:=external"), "white-box and needs the victim's weights"),
    (("policy:=missing.pt",), "missing.pt: no such policy file"),
    (("eps:=abc",), "eps:= takes float"),
])
def test_bad_arguments_are_refused_before_any_node_starts(args, message):
    out = run_graph(*args)
    assert out.returncode == 1 and message in out.stderr, out.stderr
    assert "Traceback" not in out.stderr


@pytest.mark.slow
def test_an_external_policy_that_never_appears_is_named(tmp_path):
    _, expert = policy_files(tmp_path, "HalfCheetah-v5")
    out = run_graph("policy:=external", f"expert:={expert}", "connect_timeout:=3", "record:=off")
    assert out.returncode == 1
    assert "an external policy node did not connect within 3 s" in out.stderr
    assert "publisher on /action" in out.stderr


@pytest.mark.slow
def test_set_state_validates_its_request(tmp_path):
    from rcl_interfaces.srv import SetParametersAtomically

    from aril_ros_nodes.common import param_msg

    def call(service, **params):
        client = clients[service]
        deadline = time.monotonic() + 20
        while not all(c.service_is_ready() for c in clients.values()) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        request = SetParametersAtomically.Request()
        request.parameters = [param_msg(k, v) for k, v in params.items()]
        future = client.call_async(request)
        while not future.done() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        return future.result().result

    with simulator_and_prober(cwd=tmp_path) as (_, node, executor):
        # both clients connected before the first reset: the simulator takes no client that joins later
        clients = {name: node.create_client(SetParametersAtomically, name) for name in ("sim/reset", "sim/set_state")}
        assert call("sim/reset", seed=0, episode=0).successful
        sim_here = MujocoSim("Swimmer-v5")
        state_size = sim_here.state_size
        sim_here.close()
        too_short = call("sim/set_state", state=[0.0] * 3, tag="0/0")
        assert not too_short.successful and "state must have" in too_short.reason
        nan = call("sim/set_state", state=[float("nan")] * state_size, tag="0/0")
        assert not nan.successful and "non-finite" in nan.reason
        stale = call("sim/set_state", state=[0.0] * state_size, tag="0/7")
        assert not stale.successful and "current step is 0/0" in stale.reason
        bad_reset = call("sim/reset", seed=1)
        assert not bad_reset.successful and "seed and episode" in bad_reset.reason


def start_long_run(tmp_path, domain):
    policy, expert = policy_files(tmp_path, "HalfCheetah-v5")
    log = tmp_path / "long.mcap"
    proc = subprocess.Popen([sys.executable, str(ROOT / "run_graph.py"), "mode:=physical", f"policy:={policy}",
                             f"expert:={expert}", "episodes:=50", f"record:={log}", f"domain:={domain}"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while (not log.exists() or log.stat().st_size < 200_000) and time.monotonic() < deadline:
        time.sleep(0.2)  # the log grows step by step: wait until the run is well under way
    assert proc.poll() is None, proc.stderr.read()
    return proc, log


@pytest.mark.slow
def test_ctrl_c_stops_every_node_and_closes_the_log(tmp_path):
    domain = free_domain()
    proc, log = start_long_run(tmp_path, domain)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert processes_in_domain(domain) == []
    run = read_run(log, allow_interrupted=True)
    assert len(run.tags) > 0 and run.end["interrupted"] is True
    assert run.end["reason"] == "interrupted by SIGINT"


@pytest.mark.slow
def test_a_killed_run_leaves_its_complete_steps_recoverable(tmp_path):
    domain = free_domain()
    proc, log = start_long_run(tmp_path, domain)
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 10
    while processes_in_domain(domain) and time.monotonic() < deadline:
        time.sleep(0.1)  # the nodes get SIGTERM from the kernel when their parent dies
    assert processes_in_domain(domain) == []
    with pytest.raises(RunLogError, match="cut short|truncated"):
        read_run(log)
    steps = recover(log, tmp_path / "recovered.mcap").steps
    run = read_run(tmp_path / "recovered.mcap", allow_interrupted=True)
    assert steps == len(run.tags) > 0


@pytest.mark.slow
def test_aril_a_trains_against_a_policy_node_over_ros(tmp_path):
    """Black box: the adversary only sees the actions a running policy node publishes."""
    policy, expert = policy_files(tmp_path, "Swimmer-v5")
    domain = free_domain()
    node = subprocess.Popen([sys.executable, "-m", "aril_ros_nodes.policy_node", "--ros-args", "-p",
                             "env:=Swimmer-v5", "-p", f"policy:={policy}"], env=ros_env(domain), cwd=tmp_path,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        out = subprocess.run([sys.executable, "-m", "aril_ros", "train-adversary", "env:=Swimmer-v5", "victim:=ros",
                              f"expert:={expert}", "eps:=0.1", "steps:=1024", "n_envs:=8", "rollout:=128",
                              f"out:={tmp_path / 'adv.pt'}"], env=ros_env(domain), cwd=ROOT, capture_output=True,
                             text=True, timeout=120)
        from aril_ros import plugins

        os.environ["ROS_DOMAIN_ID"] = str(domain)
        remote = plugins.load("aril_ros.victims", "ros")("Swimmer-v5")  # what victim:=ros connects to
        obs = np.random.default_rng(0).normal(size=(10, 8))
        try:
            np.testing.assert_array_equal(remote.act(obs), load_policy(policy).act(obs))  # the node's, exactly
        finally:
            remote.close()
    finally:
        node.send_signal(signal.SIGINT)
        node.wait(10)
    assert out.returncode == 0, out.stderr
    from aril_ros.adversary import load_adversary

    adversary = load_adversary(tmp_path / "adv.pt", "Swimmer-v5", "sensory")
    assert adversary.meta["provenance"]["steps"] == 1024
    assert "over ROS" in adversary.meta["provenance"]["victim_provenance"]["victim"]


@pytest.mark.slow
def test_render_records_camera_frames_beside_the_steps(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from PIL import Image
    import io

    policy, expert = policy_files(tmp_path, "Swimmer-v5")
    out = run_graph("env:=Swimmer-v5", "mode:=physical", f"policy:={policy}", f"expert:={expert}", "episodes:=2",
                    "horizon:=12", "render:=true", "render_every:=5", "render_size:=64x48",
                    f"record:={tmp_path / 'run.mcap'}")
    summary = summary_of(out)
    assert summary["camera_frames"] == 6  # steps 0, 5, 10 of each episode
    run = read_run(tmp_path / "run.mcap")  # the step reader is unaffected by the extra topic
    assert len(run.tags) == 24
    with open(tmp_path / "run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        frames = [(m.log_time, d) for _, _, m, d in reader.iter_decoded_messages(topics=["/sim/camera/image/compressed"])]
    state_stamp = dict(zip(map(str, run.tags), run.stamp_ns))
    assert [d.header.frame_id for _, d in frames] == ["0/0", "0/5", "0/10", "1/0", "1/5", "1/10"]
    for log_time, image in frames:
        assert log_time == state_stamp[image.header.frame_id] and image.format == "jpeg"
        assert Image.open(io.BytesIO(bytes(image.data))).size == (64, 48)
    recovered = tmp_path / "recovered.mcap"
    (tmp_path / "cut.mcap").write_bytes((tmp_path / "run.mcap").read_bytes()[:-1])  # recover refuses a closed log
    assert recover(tmp_path / "cut.mcap", recovered).steps == 24
    with open(recovered, "rb") as f:
        assert len(list(make_reader(f).iter_messages(topics=["/sim/camera/image/compressed"]))) == 6


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", ["gail", "dart", "dr"])
def test_trained_defenses_load_in_the_policy_node(algorithm, tmp_path):
    from aril_ros.dagger import train_learner
    from aril_ros.learner_config import LearnerConfig
    from aril_ros.gail import GailConfig, train_gail

    quiet = lambda *a, **k: None  # noqa: E731
    if algorithm == "gail":
        policy = train_gail(GailConfig(env="Swimmer-v5", steps=2048, eval_every=2048, eval_episodes=1, demos=1,
                                       out=str(tmp_path / "p.pt")), log=quiet)
    else:
        policy = train_learner(LearnerConfig(algorithm=algorithm, env="Swimmer-v5", mode="sensory", eps=0.05, rounds=1,
                                             episodes=1, epochs=1, eval_episodes=1, run_dir=str(tmp_path / "run"),
                                             out=str(tmp_path / "p.pt")), log=quiet)
    summary = summary_of(run_graph("env:=Swimmer-v5", "mode:=sensory", f"policy:={policy}", "episodes:=1",
                                   "horizon:=8", f"record:={tmp_path / 'run.mcap'}"))
    run = read_run(tmp_path / "run.mcap")
    trainer = "aril train-gail" if algorithm == "gail" else "aril train-learner"
    assert summary["steps"] == 8 and run.metadata["policy_provenance"]["command"].startswith(trainer)
    np.testing.assert_array_equal(run.action, load_policy(policy).act(run.obs))  # the node acts as the file does
