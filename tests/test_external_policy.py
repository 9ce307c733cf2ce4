"""The contract for a user's policy node (msgs_doc/README.md, "Write your own policy node"): the documented node runs
as a run's policy, a node of another architecture gets a scorecard's verdict with every question to it counted, the
doc's env table is what the envs say, and each way a node can fail is named on run_graph's stderr."""
from __future__ import annotations

import importlib.util
import json
import os
import re

import numpy as np
import pytest

from aril_ros.envs import MujocoSim, layout_of
from aril_ros.runlog import read_run
from tests.conftest import (CONTRACT, ROOT, documented_node, free_domain, policy_files, processes_in_domain, run_graph,
                            start_node, stop)


@pytest.mark.slow
@pytest.mark.parametrize("mode, env_id, attack, listeners", [("sensory", "HalfCheetah-v5", "random", 2),
                                                             ("physical", "Swimmer-v5", "spsa", 3)])
def test_the_documented_node_is_a_runs_external_policy(mode, env_id, attack, listeners, tmp_path):
    """Started first, in the domain the run is pinned to, as the doc says; the run completes with the node's actions."""
    from aril_ros_nodes.orchestrator import GraphConfig, Orchestrator

    _, expert = policy_files(tmp_path, env_id)
    domain = free_domain()
    act_dim = layout_of(env_id).act_dim
    node = start_node(documented_node(), domain, tmp_path, "-p", f"act_dim:={act_dim}", "-p", f"listeners:={listeners}")
    try:
        cfg = GraphConfig(mode=mode, env=env_id, attack=attack, eps=0.1, k=2, policy="external", expert=str(expert),
                          episodes=1, horizon=30, record=str(tmp_path / "run.mcap"), domain=str(domain))
        summary = Orchestrator(cfg, log=lambda *a, **k: None).run()
    finally:
        stop(node)
    assert node.returncode == 0, node.hung  # a SIGINT is a clean stop for it
    assert processes_in_domain(domain) == []
    run = read_run(tmp_path / "run.mcap")
    assert summary["steps"] == len(run.tags) == 30
    np.testing.assert_array_equal(run.action, np.tanh(run.obs[:, :act_dim]))  # the node's answers, as sent
    assert (summary["queries_per_step"] > 0) == (attack == "spsa")


@pytest.mark.slow
def test_training_against_the_documented_node_alone_names_its_listeners(tmp_path):
    """aril train-adversary victim:=ros asks the node with one listener on action: the doc's node, waiting for 2
    before it subscribes, never would; the error says so and how to start it, and with listeners:=1 it answers."""
    from aril_ros.protocol import ros_domain
    from aril_ros_nodes.remote_policy import RemotePolicy, RemotePolicyError

    domain = free_domain()
    for listeners, answers in ((2, False), (1, True)):
        node = start_node(documented_node(), domain, tmp_path, "-p", "act_dim:=6", "-p", f"listeners:={listeners}")
        try:
            with ros_domain(domain):
                if not answers:
                    with pytest.raises(RemotePolicyError, match="start it with --ros-args -p listeners:=1"):
                        RemotePolicy("HalfCheetah-v5", connect_timeout=15)
                    continue
                policy = RemotePolicy("HalfCheetah-v5", connect_timeout=30)
                try:
                    obs = np.random.default_rng(0).normal(size=(3, 17))
                    np.testing.assert_array_equal(policy.act(obs), np.tanh(obs[:, :6]))
                finally:
                    policy.close()
        finally:
            stop(node)
    assert processes_in_domain(domain) == []


def test_the_env_table_in_the_doc_is_the_generated_one():
    spec = importlib.util.spec_from_file_location("env_table", ROOT / "msgs_doc" / "env_table.py")
    env_table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(env_table)
    assert env_table.table_in(CONTRACT.read_text()) == env_table.env_table(), \
        "msgs_doc/README.md's env table is stale: python msgs_doc/env_table.py --write"


@pytest.mark.parametrize("env_id", ["HalfCheetah-v5", "Ant-v5", "Swimmer-v5", "Hopper-v5", "Walker2d-v5"])
def test_out_of_range_actions_move_as_clipped_but_cost_as_sent(env_id):
    """What the doc says of an action beyond the bounds: the simulator's step (MujocoSim.step, the simulator node's)
    moves the body as with the clipped action, and charges gymnasium's control cost on the action as sent."""
    sim = MujocoSim(env_id)
    layout = sim.layout
    sim.reset(3)
    start = sim.get_state()
    action = np.random.default_rng(0).uniform(-3, 3, layout.act_dim)
    clipped = np.clip(action, layout.action_low, layout.action_high)
    assert not np.array_equal(action, clipped)
    outcomes = []
    for sent in (action, clipped):
        sim.set_state(start)
        obs, reward, _, _ = sim.step(sent)
        outcomes.append((obs, sim.qpos.copy(), sim.qvel.copy(), reward))
    (obs, qpos, qvel, reward), (obs_c, qpos_c, qvel_c, reward_c) = outcomes
    sim.close()
    np.testing.assert_array_equal(obs, obs_c)
    np.testing.assert_array_equal(qpos, qpos_c)
    np.testing.assert_array_equal(qvel, qvel_c)
    weight = sim.gym_env._ctrl_cost_weight
    assert reward_c - reward == pytest.approx(weight * (np.sum(action ** 2) - np.sum(clipped ** 2)), rel=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("attack", ["fgsm", "fgsm_k"])
def test_a_white_box_attack_on_an_external_policy_is_refused_naming_the_black_box_ones(attack):
    from aril_ros_nodes.orchestrator import GraphConfig, GraphError, Orchestrator

    with pytest.raises(GraphError,
                       match=f"attack:={attack} is white-box.*black-box one: random, spsa, fd_fgsm, aril_a, transfer$"):
        Orchestrator(GraphConfig(attack=attack, policy="external", record="off"))


@pytest.mark.slow
def test_a_node_that_tags_its_answers_wrong_is_named(tmp_path):
    """It answers step <e>/<s> with the tag <e>/<s+1>: the run says so, not only the simulator's log."""
    wrong_tag = documented_node().replace(
        "        self.publisher_.publish(JointState(header=obs.header,",
        "        episode, step = obs.header.frame_id.split('/')[:2]\n"
        "        obs.header.frame_id = f'{episode}/{int(step) + 1}'\n"
        "        self.publisher_.publish(JointState(header=obs.header,")
    assert wrong_tag != documented_node()
    _, expert = policy_files(tmp_path, "HalfCheetah-v5")
    domain = free_domain()
    node = start_node(wrong_tag, domain, tmp_path)
    try:
        out = run_graph("policy:=external", f"expert:={expert}", "episodes:=1", "horizon:=20", "record:=off",
                        "step_timeout:=3", domain=domain, besides=[node.pid])
    finally:
        stop(node)
    assert out.returncode == 1
    assert re.search(r"step 0/0 made no progress for 3 s: waiting for action \(policy\).*; actions arrived tagged 0/1 "
                     r"while step 0/0 was waiting: the policy must answer with the observation's header",
                     out.stderr), out.stderr
    assert "still running" not in out.stderr


@pytest.mark.slow
def test_a_node_that_declares_probe_batches_but_answers_one_action_is_named(tmp_path):
    """It declares probe_batches and answers every message with one action: the run stops at the first probe batch
    and says which, how many values came and how many a probe takes."""
    declares = documented_node().replace(
        "        self.listeners = self.declare_parameter('listeners', 2).value",
        "        self.declare_parameter('probe_batches', True)\n"
        "        self.listeners = self.declare_parameter('listeners', 2).value")
    assert declares != documented_node()
    _, expert = policy_files(tmp_path, "HalfCheetah-v5")
    domain = free_domain()
    node = start_node(declares, domain, tmp_path, "-p", "listeners:=3")
    try:
        out = run_graph("policy:=external", f"expert:={expert}", "attack:=spsa", "k:=1", "episodes:=1", "horizon:=5",
                        "record:=off", domain=domain, besides=[node.pid])
    finally:
        stop(node)
    assert out.returncode == 1
    # SPSA^k's first question: the true state and its 2 x 8 directions, in one batch
    assert ("step 0/0: the policy node answered 6 action values to probe batch 0/0/probe/0..16 (17 probes), "
            "HalfCheetah-v5 takes 6 a probe") in out.stderr, out.stderr


@pytest.mark.slow
def test_a_run_without_its_external_node_says_how_to_start_one(tmp_path):
    _, expert = policy_files(tmp_path, "HalfCheetah-v5")
    domain = free_domain()
    out = run_graph("policy:=external", f"expert:={expert}", "connect_timeout:=6", "record:=off", domain=domain)
    assert out.returncode == 1
    join = f"ROS_DOMAIN_ID={domain} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST <your node's command>, answering once " \
           "action has 2 subscribers"
    reminder = re.escape("[run_graph] waiting for the external policy node (") + r"\d s left\): " + re.escape(
        f"a subscriber on /observation and a publisher on /action; start it with {join}")
    assert len(re.findall(reminder, out.stderr)) == 1, out.stderr  # every 5 s
    assert f"run_graph: error: an external policy node did not connect within 6 s: no node but the run's own has a " \
           f"subscriber on /observation or a publisher on /action in ROS domain {domain}; start it with {join}; " \
           in out.stderr, out.stderr


@pytest.mark.slow
@pytest.mark.parametrize("ros_args, reliability, cause", [
    (("-p", "listeners:=3"), "RELIABLE", ("node 'my_policy' publishes on /action but has not subscribed to "
                                          "/observation: a node that waits for subscribers on action first must wait "
                                          "for 2, not more")),
    ((), "BEST_EFFORT", "node 'my_policy' publishes on /action best effort, which no reliable subscription matches"),
], ids=["too many listeners", "best effort"])
def test_a_node_that_never_subscribes_is_told_why(ros_args, reliability, cause, tmp_path):
    """The documented node waiting for more listeners than the run has, or publishing best effort."""
    from aril_ros_nodes.orchestrator import GraphConfig, GraphError, Orchestrator

    _, expert = policy_files(tmp_path, "HalfCheetah-v5")
    domain = free_domain()
    code = documented_node()
    assert "ReliabilityPolicy.RELIABLE" in code
    node = start_node(code.replace("ReliabilityPolicy.RELIABLE", f"ReliabilityPolicy.{reliability}"), domain,
                      tmp_path, *ros_args)
    message = (f"an external policy node did not connect within 8 s: no node but the run's own has a subscriber on "
               f"/observation in ROS domain {domain}; {cause}")
    try:  # in this process, as aril train-learner source:=graph runs it: the same error run_graph prints
        with pytest.raises(GraphError, match=re.escape(message)):
            Orchestrator(GraphConfig(policy="external", expert=str(expert), connect_timeout=8, record="off",
                                     domain=str(domain)), log=lambda *a, **k: None).run()
    finally:
        stop(node)
    assert processes_in_domain(domain) == []


ANOTHER_ARCHITECTURE = '''

def elu(x):
    return np.where(x > 0, x, np.expm1(np.minimum(x, 0)))


class ThreeLayers:
    """Not aril_ros's policy: numpy, three hidden layers of 24 (ELU, sin, ELU), the observation centred and scaled by
    figures of its own and cut at +-5, the action clipped to the bounds; seeded random weights."""

    def __init__(self, obs_dim, act_dim, seed=7):
        rng = np.random.default_rng(seed)
        self.center, self.spread = rng.normal(0, 0.5, obs_dim), rng.uniform(0.5, 2.0, obs_dim)
        sizes = (obs_dim, 24, 24, 24, act_dim)
        self.layers = [(rng.normal(0, 1.5 / np.sqrt(n), (n, m)), rng.normal(0, 0.1, m))
                       for n, m in zip(sizes, sizes[1:])]
        self.activations = (elu, np.sin, elu, lambda x: np.clip(x, -1.0, 1.0))

    def __call__(self, obs):
        x = np.clip((obs - self.center) / self.spread, -5.0, 5.0)
        for (weight, bias), activation in zip(self.layers, self.activations):
            x = activation(x @ weight + bias)
        return x
'''
"""Put before the documented node's class: the policy the node serves."""


def another_architectures_node() -> str:
    """The documented node serving :data:`ANOTHER_ARCHITECTURE`, writing on exit the frame_id of every observation
    it answered, in order, to the file its ``answered`` parameter names."""
    code = documented_node()
    for old, new in (
            ("import numpy as np\n", "import atexit\nfrom pathlib import Path\n\nimport numpy as np\n"),
            ("\n\nclass MyPolicy(Node):", ANOTHER_ARCHITECTURE + "\n\nclass MyPolicy(Node):"),
            ("        self.publisher_ = ",
             "        self.policy = ThreeLayers(self.declare_parameter('obs_dim', 8).value, self.act_dim)\n"
             "        self.answered = []\n"
             "        answered = Path(self.declare_parameter('answered', '').value)\n"
             "        atexit.register(lambda: answered.write_text(''.join(f'{tag}\\n' for tag in self.answered)))\n"
             "        self.publisher_ = "),
            ("np.tanh(np.asarray(obs.position[:self.act_dim]))", "self.policy(np.asarray(obs.position))"),
            ("        self.publisher_.publish(JointState(header=obs.header,",
             "        self.answered.append(obs.header.frame_id)\n"
             "        self.publisher_.publish(JointState(header=obs.header,")):
        assert code.count(old) == 1, old
        code = code.replace(old, new)
    return code


def runs_answered(tags: list[str]) -> list[tuple[int, int]]:
    """The node's answers, run by run, as (steps, probes): a run starts at step 0/0, and a probe belongs to the step it
    was asked during, the next one answered (its questions come first); probes before a run's first step belong to
    it, so a surrogate's, asked between two runs, count with the run after them."""
    runs, probes = [], 0
    for tag in tags:
        if "/probe/" in tag:
            probes += 1
            continue
        if tag == "0/0":
            runs.append([0, 0])
        runs[-1][0] += 1
        runs[-1][1] += probes
        probes = 0
    assert probes == 0, "probes after the last step"
    return [tuple(run) for run in runs]


@pytest.fixture(scope="module")
def another_architectures_card(tmp_path_factory):
    """``aril scorecard policy:=external budget:=quick`` against a node of the user's own (not aril_ros's MLPPolicy:
    another depth, activations and normalisation), shortened: both modes, the quick budget's black-box rows through
    the graph, 2 episodes of 20 steps, a 2048-step ARIL-A trained in process (workers:=1: no Ray for seconds-long
    trainings). Returns the scorecard's folder, its JSON and page, the frame_id of every observation the node
    answered, in order, and the node's policy."""
    from aril_ros.scorecard import ScorecardConfig, scorecard

    tmp_path = tmp_path_factory.mktemp("another-architecture")
    env_id, layout = "Swimmer-v5", layout_of("Swimmer-v5")
    answered = tmp_path / "answered.txt"
    domain = free_domain()
    node = start_node(another_architectures_node(), domain, tmp_path, "-p", f"obs_dim:={layout.obs_dim}",
                      "-p", f"act_dim:={layout.act_dim}", "-p", f"answered:={answered}")
    try:
        page = scorecard(ScorecardConfig(policy="external", domain=str(domain), env=env_id, budget="quick",
                                         episodes=2, horizon=20, adversary_steps=2048, keep_logs=True, workers=1,
                                         out=str(tmp_path / "card")), log=lambda *a, **k: None)
    finally:
        stop(node)
    assert node.returncode == 0, node.hung
    assert processes_in_domain(domain) == []
    namespace = {"np": np}
    exec(ANOTHER_ARCHITECTURE, namespace)
    card = json.loads((tmp_path / "card" / "scorecard.json").read_text())
    return (tmp_path / "card", card, page.read_text(), answered.read_text().splitlines(),
            namespace["ThreeLayers"](layout.obs_dim, layout.act_dim))


@pytest.mark.slow
def test_the_quick_budget_runs_its_rows_on_the_same_seeds_and_steps_on_no_probes_answer(another_architectures_card):
    """The quick budget through the graph: each mode's black-box rows, each cell on the same seeds; each ARIL-A
    asks its questions per step as probes, all in the run's log, and the steps are the node's answers to the
    observations stepped on. The quick budget unshortened is measured in docs/scoring.md."""
    from aril_ros.scorecard import QUICK_ROWS
    from aril_ros.verdict import SEARCH

    folder, card, text, _, policy = another_architectures_card
    seeds = [card["settings"]["seed"] + i for i in range(2)]
    assert list(card["modes"]) == ["sensory", "physical"]
    for mode, result in card["modes"].items():
        assert list(result["attacks"]) == list(QUICK_ROWS[mode])
        for attack, sweep in result["attacks"].items():
            for cell in sweep.values():
                assert [e["env_seed"] for e in cell["episodes"]] == seeds
                assert {e["steps"] for e in cell["episodes"]} == {20}
        # ARIL-A asks the node its action a step, and with search SEARCH + 1 candidates more; FGSM by finite
        # differences two questions per perturbed entry, the directed ARIL-A its action and as many: all probes in
        # the log
        entries = layout_of(card["settings"]["env"]).n_position
        logs = {"aril_a": (f"aril_a-adversary-{mode}", 1),
                "aril_a_search": (f"aril_a-adversary-{mode}-search{SEARCH}", SEARCH + 2),
                "aril_a_directed": (f"aril_a-directed-{mode}", 1 + 2 * entries),
                "fd_fgsm": ("fd_fgsm", 2 * entries)}
        assert set(result["attacks"]) <= set(logs)
        for attack, (name, asked) in logs.items():
            if attack not in result["attacks"]:
                continue
            run = read_run(folder / "logs" / f"{mode}-{name}-{result['eps']:g}.mcap")
            assert set(run.probes_per_step) == {result["attacks"][attack]["1.0"]["queries_per_step"]} == {asked}
            # no probe's answer was stepped on: the node's own answer to each observation (one at a time, as it is asked)
            np.testing.assert_array_equal(run.action, [policy(obs) for obs in run.obs])
        assert (folder / f"sweep-{mode}.png").stat().st_size > 0
        at_eps = {attack: sweep["1.0"]["mean_return"] for attack, sweep in result["attacks"].items()}
        assert result["worst"]["attack"] == min(at_eps, key=at_eps.get)
        assert f"## {mode}," in text


@pytest.mark.slow
def test_a_policy_of_another_architecture_gets_a_verdict_with_every_question_counted(another_architectures_card):
    """Every row of the black-box pipeline has its figure, and the node answered exactly what the scorecard says it
    was asked: each run's steps (the clean one's and the timing row's too), each cell's questions, and what each mode's
    rows needed asked (after those two runs, before the first cell's): in physical mode the surrogate's, ARIL-A
    training's and its states' screening's questions, in sensory mode the directed zoo's screening's, the directed
    ARIL-A training's and its states' screening's. The zoo's
    row asks as the ARIL-A row does, with another file, and SPSA^k's questions are counted in test_scorecard."""
    _, card, _, tags, _ = another_architectures_card
    cells = []
    for mode, result in card["modes"].items():
        for attack, sweep in result["attacks"].items():
            cell = sweep["1.0"]
            assert np.isfinite(cell["mean_return"]) and [e["steps"] for e in cell["episodes"]] == [20, 20]
            cells.append(cell)
        assert np.isfinite(result["worst"]["drop_pct"])
        per_step = {attack: sweep["1.0"]["queries_per_step"] for attack, sweep in result["attacks"].items()}
        # Swimmer: 3 perturbed entries
        assert per_step == {"sensory": {"fd_fgsm": 6, "aril_a_directed": 7}, "physical": {"aril_a": 1}}[mode]
    steps = lambda cell: sum(e["steps"] for e in cell["episodes"])  # noqa: E731
    sensory, physical = card["modes"]["sensory"], card["modes"]["physical"]
    assert "surrogate" not in sensory and "directed" not in physical  # what each mode's quick rows need, no more
    # in the order the node was asked (each connection's questions numbered from 0): the physical copy, the directed
    # zoo's screening (every member kept: no file to leave out), then the two trainings (workers:=1, one after the
    # other) and the screenings of their states
    in_turn = [physical["surrogate_queries"], sensory["directed_zoo_queries"], physical["adversary_queries"],
               sensory["directed_queries"], physical["adversary_states_queries"], sensory["directed_states_queries"]]
    assert all(queries > 0 for queries in in_turn)
    asked = sum(in_turn)
    clean = card["modes"]["sensory"]["clean"]
    late = list(card["timing"]["policies"]["external"]["cells"].values())  # the quick budget's timing row, no probes
    assert len(late) == 1 and [e["steps"] for e in late[0]["episodes"]] == [20, 20]
    before = steps(clean) + sum(map(steps, late))  # the runs before the pipelines ask the node anything
    assert len(tags) == before + sum(steps(cell) + cell["queries"] for cell in cells) + asked
    expected = [(steps(clean), 0)] + [(steps(cell), 0) for cell in late] + [(steps(cell), cell["queries"])
                                                                             for cell in cells]
    expected[1 + len(late)] = (expected[1 + len(late)][0], expected[1 + len(late)][1] + asked)
    assert runs_answered(tags) == expected
    # between the timing run and the first cell's, each as many questions as the page says
    between = tags[before:before + asked]  # the first cell's own questions follow (fd_fgsm's before its first step)
    starts = [i for i, tag in enumerate(between) if tag.endswith("/probe/0")]
    assert np.diff([*starts, len(between)]).tolist() == in_turn
    # ARIL-A: two questions a training step; the directed one's: its input, the actor's two per entry, the answer
    assert physical["adversary_queries"] >= 2 * 2048 and sensory["directed_queries"] >= (2 + 2 * 3) * 2048
    assert all(cell["queries"] == cell["queries_per_step"] * steps(cell) for cell in cells)
