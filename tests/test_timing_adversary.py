"""The learned timing adversary (aril_ros.timing_adversary): trained by ARIL-A's PPO with time for values, reproducibly,
its file checked against the budget and env it is played with, and its trainer's episodes held to the budget's rules
as the engine's are."""
import json

import numpy as np
import pytest
import torch

from aril_ros.adversary import AdversaryConfig, TimingPlay, check_config, initial_timing_adversary, train_adversary
from aril_ros.envs import layout_of
from aril_ros.policy import PolicyFileError, load_policy
from aril_ros.timing import TimingAttack, TimingBudget, TimingChoice
from aril_ros.timing_adversary import load_timing_adversary
from tests.conftest import policy_files
from tests.test_timing import timing_adversary

BUDGET = TimingBudget(delay=2, drop=0.2, action_delay=1)


def test_a_timeline_plays_each_row_at_its_own_step_as_if_alone():
    """The trainer's simulators begin their episodes at different steps: one timeline with a step per row (and a row
    restarted) gives each row what a timeline of that row alone gives."""
    rng = np.random.default_rng(0)
    n, steps, obs_dim, act_dim = 3, 30, 4, 2
    starts = [0, 7, 12]  # row r begins its episode at the trainer's step starts[r]
    shared = TimingAttack(BUDGET, "random").timeline(n, obs_dim, act_dim, [])
    alone = [TimingAttack(BUDGET, "random").timeline(1, obs_dim, act_dim, []) for _ in range(n)]
    for k in range(steps):
        obs, actions = rng.normal(size=(n, obs_dim)), rng.normal(size=(n, act_dim))
        asked = TimingChoice(rng.integers(0, 3, n), rng.random(n) < 0.5, rng.integers(0, 2, n))
        t = np.array([k - s if k >= s else k for s in starts])
        for r in range(n):
            if k == starts[r] and k:
                shared.restart([r])
                alone[r] = TimingAttack(BUDGET, "random").timeline(1, obs_dim, act_dim, [])
        rows = np.arange(n)
        seen, age, dropped = shared.deliver(t, obs, rows, asked)
        applied, action_age = shared.apply(t, actions, rows)
        for r in range(n):
            mine = TimingChoice(asked.obs_age[[r]], asked.drop[[r]], asked.action_age[[r]])
            one = alone[r].deliver(int(t[r]), obs[[r]], np.zeros(1, dtype=np.int64), mine)
            one_applied = alone[r].apply(int(t[r]), actions[[r]], np.zeros(1, dtype=np.int64))
            np.testing.assert_array_equal(seen[r], one[0][0])
            assert (age[r], dropped[r], action_age[r]) == (one[1][0], one[2][0], one_applied[1][0])
            np.testing.assert_array_equal(applied[r], one_applied[0][0])


def test_the_trainer_plays_within_the_budget(tmp_path):
    """Whatever the adversary asks, what the trainer plays holds the budget: ages within it, drops within the share of
    every prefix of a row's episode, actions applied no older than the action delay."""
    policy, expert = policy_files(tmp_path, "Swimmer-v5")
    cfg = AdversaryConfig(env="Swimmer-v5", mode="clean", delay=2, drop=0.2, action_delay=1, n_envs=2)
    obs_dim = layout_of("Swimmer-v5").obs_dim
    net = initial_timing_adversary(cfg, np.zeros(obs_dim), np.ones(obs_dim))
    play = TimingPlay(cfg, net, load_policy(policy))
    gen, rows = torch.Generator().manual_seed(0), range(2)
    drops = np.zeros(2)
    for t in range(60):
        obs = np.random.default_rng(t).normal(size=(2, obs_dim))
        x = torch.as_tensor(play.inputs(obs, None, None, rows), dtype=torch.float32)
        sample, _, _ = net.sample(x, gen)
        before = play.timeline.drops.copy()
        play.act(torch.full_like(sample, 5.0), obs, rows)  # asks beyond every budget
        drops = play.timeline.drops.copy()
        late = (t - play.timeline.last_seen)[drops == before]  # a drop shows the last seen again, however old
        assert (late == min(2, t)).all() and (play.timeline.action_age() == 1).all()
        assert (drops <= 0.2 * (t + 1) + 1e-9).all()
    assert drops.min() > 0  # drops were played, as many as the share allows


def test_a_timing_adversary_trains_reproducibly_and_its_file_says_what_it_was_trained_for(tmp_path):
    policy, expert = policy_files(tmp_path, "Swimmer-v5")
    first = timing_adversary(BUDGET, tmp_path, "Swimmer-v5", policy, expert, seed=3)
    lines = []
    again = train_adversary(AdversaryConfig(
        env="Swimmer-v5", mode="clean", delay=2, drop=0.2, action_delay=1, victim=str(policy), expert=str(expert),
        steps=2048, n_envs=4, rollout=128, minibatch=128, warmup=5, seed=3, out=str(tmp_path / "again.pt")),
        log=lambda line, **_: lines.append(line))
    one, two = load_timing_adversary(first), load_timing_adversary(again)
    for (name, a), (_, b) in zip(one.state_dict().items(), two.state_dict().items(), strict=True):
        assert torch.equal(a, b), name
    assert one.meta["budget"] == {"delay": 2, "drop": 0.2, "action_delay": 1}
    assert one.meta["provenance"]["victim_sha256"] and one.meta["provenance"]["steps"] == 2048
    assert lines[0].startswith("[train-adversary Swimmer-v5 delay 2, drop 0.2, action delay 1] step      512")
    assert json.loads(lines[-1])["steps"] == 2048
    # the file's budget and env are the ones it is played with, or it is refused naming both
    with pytest.raises(PolicyFileError, match=r"trained for delay 2, drop 0.2, action delay 1; played with delay 1, "
                                              r"drop 0.2, action delay 1"):
        TimingAttack(TimingBudget(1, 0.2, 1), "learned", str(again)).timeline(1, 8, 2, [])
    with pytest.raises(ValueError, match=r"trained on Swimmer-v5's observations \(8 entries\), not these \(17\)"):
        TimingAttack(BUDGET, "learned", str(again)).timeline(1, 17, 6, [])
    with pytest.raises(PolicyFileError, match="not an aril_ros timing-adversary file"):
        TimingAttack(BUDGET, "learned", str(policy)).timeline(1, 8, 2, [])


def test_the_settings_of_a_timing_adversary_are_checked():
    with pytest.raises(ValueError, match="timing:=learned plays a timing adversary: give its file as timing_file:="):
        TimingAttack(BUDGET, "learned")
    with pytest.raises(ValueError, match="timing_file:=x.pt is played by timing:=learned, got timing:=random"):
        TimingAttack(BUDGET, "random", "x.pt")
    with pytest.raises(ValueError, match="mode:=clean trains a timing adversary: give its budget"):
        check_config(AdversaryConfig(mode="clean"))
    with pytest.raises(ValueError, match="mode:=sensory trains a value adversary, and one of both is not built"):
        check_config(AdversaryConfig(mode="sensory", delay=1))
