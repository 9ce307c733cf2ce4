"""Query-based attacks through the graph: their probes go to the policy node and back on the step topics, are
recorded as probes, and never change the trajectory."""
from __future__ import annotations

import time

import numpy as np
import pytest

from aril_ros import protocol as P
from aril_ros.attacks import make_attack
from aril_ros.envs import MujocoSim, layout_of
from aril_ros.policy import load_policy
from aril_ros.protocol import ProbeTag, StepTag
from aril_ros.rollout import RolloutEngine
from aril_ros.runlog import RunLogError, RunLogWriter, read_run, recover
from tests.conftest import (assert_same_steps, cdr, free_domain, policy_files, ros_env, run_graph, run_with_external,
                            simulator_and_prober, step_messages, summary_of)


def test_a_probe_tag_names_its_step_and_is_no_step_tag():
    probe = ProbeTag(StepTag(3, 127), 5)
    assert str(probe) == "3/127/probe/5" and ProbeTag.parse("3/127/probe/5") == probe
    assert P.is_probe("3/127/probe/5") and not P.is_probe("3/127") and not P.is_probe("3/127/probe/x")
    with pytest.raises(ValueError, match="not a step tag"):
        StepTag.parse(str(probe))
    with pytest.raises(ValueError, match="not a probe tag"):
        ProbeTag.parse("3/127")
    # a probe batch: rows 5 to 7 in one message; a batch has two rows at least
    batch = ProbeTag(StepTag(3, 127), 5, 3)
    assert str(batch) == "3/127/probe/5..7" and ProbeTag.parse("3/127/probe/5..7") == batch
    assert P.probe_rows("3/127/probe/5..7") == 3 and P.probe_rows("3/127/probe/5") == P.probe_rows("3/127") == 1
    assert not P.is_probe("3/127/probe/5..5") and not P.is_probe("3/127/probe/5..")


def message_counts(log) -> dict[str, int]:
    from mcap.reader import make_reader

    with open(log, "rb") as f:
        summary = make_reader(f).get_summary()
    return {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}


# aril_a's sensory probes without search: test_graph's graph≡engine test (its adversary takes actions)
@pytest.mark.slow
@pytest.mark.parametrize("mode, attack, batches", [("sensory", "spsa", True), ("physical", "spsa", True),
                                                   ("physical", "aril_a", True), ("sensory", "fd_fgsm", True),
                                                   ("sensory", "spsa", False)])
def test_probes_keep_the_graph_bit_exact_with_the_engine_and_are_logged_apart(mode, attack, batches, tmp_path):
    from aril_ros.adversary import AdversaryConfig, train_adversary

    env_id, horizon = "Swimmer-v5", 25
    policy, expert = policy_files(tmp_path, env_id)
    adversary = None
    if attack == "aril_a":  # takes the victim's and the expert's actions (1 probe), and searches (4 + 1 more)
        adversary = str(train_adversary(AdversaryConfig(env=env_id, mode=mode, eps=0.1, victim=str(policy),
                                                        expert=str(expert), steps=0, out=str(tmp_path / "adv.pt")),
                                        log=lambda *a, **k: None))
    log = tmp_path / "run.mcap"
    knobs = {"spsa": ("k:=2",), "fd_fgsm": ()}.get(attack, (f"attack_file:={adversary}", "search:=4"))
    summary = summary_of(run_graph(f"mode:={mode}", f"env:={env_id}", f"policy:={policy}", f"expert:={expert}",
                                   f"attack:={attack}", "eps:=0.1", "episodes:=2", f"horizon:={horizon}", "seed:=4",
                                   f"record:={log}", f"probe_batches:={batches}", *knobs))
    victim, labeller = load_policy(policy), load_policy(expert)
    engine_attack = make_attack(attack, layout_of(env_id), 0.1, victim=victim, expert=labeller,
                                steps=2 if attack == "spsa" else None, adversary=adversary, mode=mode,
                                search=4 if attack == "aril_a" else 0)
    traj = RolloutEngine(env_id, victim, labeller, engine_attack, mode, n_envs=2, horizon=horizon).rollout(2, seed=4)
    run = read_run(log)
    assert_same_steps(run, traj)
    # every step asked as many probes as the engine's attack did, and the summary says so
    assert engine_attack.queries_per_step == {"spsa": 35, "fd_fgsm": 2 * 3}.get(attack, 6)
    assert (run.probes_per_step == engine_attack.queries_per_step).all()
    assert summary["queries_per_step"] == engine_attack.queries_per_step
    # probes are the policy's answers, kept apart: the step's action is the one applied, on what the policy saw
    np.testing.assert_array_equal(run.probe_action, victim.act(run.probe_obs))
    np.testing.assert_array_equal(run.action, victim.act(run.obs))
    first = np.concatenate([[0], np.cumsum(run.probes_per_step)[:-1]])
    # each step first asks about the true state (fd_fgsm: moved by its first difference)
    first_move = engine_attack.moves[0] if attack == "fd_fgsm" else 0.0
    np.testing.assert_array_equal(run.probe_obs[first], run.true_obs + first_move)
    counts = message_counts(log)
    assert counts["/observation"] == counts["/action"] == len(run.tags)
    # in batches, one message for each time the attack asks (spsa: the true state, then each iteration's directions;
    # aril_a: its input action, then the search's candidates); else one a probe
    asks = {"spsa": 1 + 2, "fd_fgsm": 1}.get(attack, 2) * len(run.tags) if batches else len(run.probe_row)
    assert counts["/probe/observation"] == counts["/probe/action"] == asks


def test_an_external_policy_node_is_attacked_by_queries_alone(tmp_path):
    summary = summary_of(run_with_external("good", tmp_path, "attack:=spsa", "k:=1", "horizon:=10"))
    run = read_run(tmp_path / "run.mcap")
    assert summary["steps"] == 10 and summary["queries_per_step"] == 18  # 1 + k (2 * 8 samples + 1)
    np.testing.assert_array_equal(run.action, np.tanh(0.5 * run.obs[:, :6]))
    np.testing.assert_array_equal(run.probe_action, np.tanh(0.5 * run.probe_obs[:, :6]))
    assert np.abs(run.delta).max() == pytest.approx(0.1)


def test_the_simulator_never_steps_on_a_probe():
    """A probe's answer tagged with the current step, even a malformed one, neither steps nor stops it."""
    from rcl_interfaces.srv import SetParametersAtomically
    from sensor_msgs.msg import JointState

    from aril_ros_nodes.common import STEP_QOS, joint_state, param_msg, step_header

    with simulator_and_prober() as (sim, node, executor):
        heard: dict[str, JointState] = {}
        node.create_subscription(JointState, P.STATE, lambda m: heard.setdefault(m.header.frame_id, m), STEP_QOS)
        rewards = node.create_subscription(JointState, P.REWARD, lambda m: heard.setdefault("reward", m), STEP_QOS)
        actions = node.create_publisher(JointState, P.ACTION, STEP_QOS)
        reset = node.create_client(SetParametersAtomically, P.RESET_SERVICE)

        def spin_until(done, seconds):
            deadline = time.monotonic() + seconds
            while not done() and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)

        spin_until(lambda: reset.service_is_ready() and actions.get_subscription_count() and
                   rewards.get_publisher_count(), 30)
        request = SetParametersAtomically.Request()
        request.parameters = [param_msg("seed", 3), param_msg("episode", 0)]
        future = reset.call_async(request)
        spin_until(future.done, 10)
        assert future.result().result.successful
        probe = step_header(ProbeTag(StepTag(0, 0), 0), 0)
        actions.publish(joint_state(probe, ["a", "b"], effort=[1.0, -1.0]))
        actions.publish(joint_state(probe, ["a"], effort=[float("nan")]))  # would stop it, were it the step's
        spin_until(lambda: "reward" in heard, 1.0)
        assert "reward" not in heard and sim.poll() is None
        action = np.array([0.3, -0.2])
        actions.publish(joint_state(step_header(StepTag(0, 0), 0), ["a", "b"], effort=action))
        spin_until(lambda: "0/1" in heard and "reward" in heard, 10)  # two topics: either may come first
        reference = MujocoSim("Swimmer-v5")
        reference.reset(3)
        obs, reward, _, _ = reference.step(action)
        reference.close()
        assert heard["reward"].position[0] == reward
        np.testing.assert_array_equal(heard["0/1"].position, obs)


def probe_messages(probe: ProbeTag, stamp: int, answers: int | None = None) -> dict[str, bytes]:
    """A probe's (or a probe batch's) observation, row k being (9, k), and its answer (-k): ``answers`` rows of it."""
    from aril_ros_nodes.common import step_header

    header = step_header(probe, stamp)
    rows = range(probe.index, probe.index + probe.rows)
    return {P.OBSERVATION: cdr(header, ["x", "y"], position=[v for k in rows for v in (9.0, float(k))]),
            P.ACTION: cdr(header, ["u"], effort=[-float(k) for k in rows][:answers])}


def test_the_recorder_writes_a_step_once_its_probes_are_answered_and_the_reader_keeps_them_apart(tmp_path):
    from aril_ros.runlog import StepRecorder

    meta = {"env": "test", "mode": "sensory", "eps": 0.0, "obs_names": ["x", "y"], "zero_order": [True, False],
            "action_names": ["u"]}
    writer = RunLogWriter(tmp_path / "run.mcap", meta)
    recorder = StepRecorder(writer)
    recorder.start_episode(0)
    first, second = (StepTag(0, 0), 0), (StepTag(0, 1), 50_000_000)
    probes = [probe_messages(ProbeTag(first[0], k), first[1]) for k in range(2)]
    for k in (1, 0):  # the policy's answers precede the step's action; one probe's observation comes late
        recorder.on_message(P.ACTION, probes[k][P.ACTION])
    recorder.on_message(P.OBSERVATION, probes[0][P.OBSERVATION])
    for topic, raw in step_messages(*first, done=False).items():
        recorder.on_message(topic, raw)
    assert recorder.steps_written == 0 and "1 probes' observation or answer" in recorder.missing_text()
    recorder.on_message(P.OBSERVATION, probes[1][P.OBSERVATION])
    assert recorder.steps_written == 1 and recorder.probes_answered == 2
    recorder.on_message(P.OBSERVATION, probes[1][P.OBSERVATION])  # asked again after its step was written
    batch = probe_messages(ProbeTag(second[0], 0, 3), second[1])  # three probes in one message, and their answers
    for topic, raw in [*batch.items(), *step_messages(*second, done=True).items()]:
        recorder.on_message(topic, raw)
    assert recorder.steps_written == 2 and recorder.probes_answered == 2 + 3 and recorder.episode_done
    recorder.close(interrupted=False)
    complete = (tmp_path / "run.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(complete[:-1])  # a closed log is not recovered: cut its final magic
    assert recover(tmp_path / "cut.mcap", tmp_path / "recovered.mcap").steps == 2
    for log in (tmp_path / "run.mcap", tmp_path / "recovered.mcap"):
        run = read_run(log, allow_interrupted=True)
        np.testing.assert_array_equal(run.obs, [[0.0, 1.0], [1.0, 1.0]])  # the steps, as without probes
        np.testing.assert_array_equal(run.action, [[0.5], [0.5]])
        np.testing.assert_array_equal(run.probes_per_step, [2, 3])
        np.testing.assert_array_equal(run.probe_obs, [[9.0, 0.0], [9.0, 1.0], [9.0, 0.0], [9.0, 1.0], [9.0, 2.0]])
        np.testing.assert_array_equal(run.probe_action, [[0.0], [-1.0], [0.0], [-1.0], [-2.0]])
        np.testing.assert_array_equal(run.probe_row, [0, 0, 1, 1, 1])
        assert message_counts(log)["/probe/action"] == 3
    # a batch answered with fewer actions than it asked is refused by every reader, naming the batch
    short = RunLogWriter(tmp_path / "short.mcap", meta)
    short.write_step(first[1], step_messages(*first, done=False),
                     [probe_messages(ProbeTag(first[0], 0, 2), first[1], answers=1)])
    short.write_step(second[1], step_messages(*second, done=True))
    short.close(interrupted=False, episodes=[])
    with pytest.raises(RunLogError, match=r"probe 0/0/probe/0\.\.1 probe/action: 1 values, the run's layout has 1 a "
                                          r"probe, 2 probes"):
        read_run(tmp_path / "short.mcap")


@pytest.mark.slow
def test_queries_victim_says_which_attacks_ask_the_policy(tmp_path):
    from aril_ros.adversary_net import load_adversary
    from aril_ros.attacks import queries_victim
    from aril_ros.registry import adversary_path

    takes_actions = load_adversary(adversary_path("Swimmer-v5", "sensory"))
    assert takes_actions.takes_actions
    state_only = state_only_adversary(tmp_path)
    attacks = ("none", "random", "fgsm", "fgsm_k", "spsa", "fd_fgsm")
    assert [queries_victim(a) for a in attacks] == [False] * 4 + [True] * 2
    assert queries_victim("aril_a", takes_actions) and queries_victim("aril_a", state_only, search=2)
    assert not queries_victim("aril_a", state_only)
    # so the orchestrator has the policy node wait for the attacker's probe client on action too
    from aril_ros_nodes.graph_config import GraphConfig, plan_run

    policy, expert = policy_files(tmp_path, "Swimmer-v5")
    for attack, listeners in (("random", 2), ("spsa", 3)):
        run = plan_run(GraphConfig(env="Swimmer-v5", mode="sensory", attack=attack, policy=str(policy),
                                   expert=str(expert), record="off"))
        assert run.action_listeners == listeners and run.node_params()["policy"]["listeners"] == listeners


def state_only_adversary(tmp_path):
    from aril_ros.adversary import AdversaryConfig, train_adversary
    from aril_ros.adversary_net import load_adversary

    policy, expert = policy_files(tmp_path, "Swimmer-v5")
    return load_adversary(train_adversary(AdversaryConfig(env="Swimmer-v5", mode="sensory", eps=0.1, victim=str(policy),
                                                          expert=str(expert), inputs="state", steps=0,
                                                          out=str(tmp_path / "state-only.pt")),
                                          log=lambda *a, **k: None))


@pytest.mark.slow
def test_the_policy_node_is_ready_only_once_every_listener_on_action_has_matched(tmp_path, monkeypatch):
    """Under a query attack the attacker's probe client listens on action too. A policy node ready at two
    subscribers could then answer step 0 before the simulator has matched its publisher, and that action
    would be lost (a run stalled at step 0/0): it waits for the ``listeners`` the orchestrator names."""
    import subprocess
    import sys

    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from aril_ros_nodes.common import READY_QOS, STEP_QOS

    domain = free_domain()
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    policy, _ = policy_files(tmp_path, "Swimmer-v5")
    node = subprocess.Popen([sys.executable, "-m", "aril_ros_nodes.policy_node", "--ros-args", "-p", "env:=Swimmer-v5",
                             "-p", f"policy:={policy}", "-p", "listeners:=3"], env=ros_env(domain),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    context = rclpy.Context()
    rclpy.init(args=[], context=context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    try:
        peer = rclpy.create_node("peers", context=context)
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(peer)
        announced = []
        peer.create_subscription(String, P.READY, lambda msg: announced.append(msg.data), READY_QOS)
        peer.create_publisher(JointState, P.OBSERVATION, STEP_QOS)  # it waits for observations' publisher too
        listeners = [peer.create_subscription(JointState, P.ACTION, lambda msg: None, STEP_QOS) for _ in range(2)]

        def spin_until(done, seconds):
            deadline = time.monotonic() + seconds
            while not done() and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)
            return done()

        assert spin_until(lambda: all(s.get_publisher_count() for s in listeners), 30), "the policy node never came up"
        assert not spin_until(lambda: announced, 3), "ready with two of its three listeners"
        listeners.append(peer.create_subscription(JointState, P.ACTION, lambda msg: None, STEP_QOS))
        assert spin_until(lambda: announced, 15) and announced == ["policy"]
    finally:
        # destroyed, not only shut down: its observation publisher would stay in the domain, which this process's
        # next run takes again (free_domain), and that run would stop it as an intruder
        executor.shutdown()
        peer.destroy_node()
        rclpy.try_shutdown(context=context)
        node.kill()
        node.wait()
