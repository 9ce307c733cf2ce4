import numpy as np
import pytest
import torch

from aril_ros.adversary import (AdversaryConfig, load_adversary, ready_adversaries, ready_adversary, save_adversary,
                                snapshots_of, train_adversary, trained_for)
from aril_ros.attacks import LearnedAttack, make_attack
from tests.conftest import AnswersOnly, local_ray
from aril_ros.envs import layout_of
from aril_ros.policy import PolicyFileError, save_policy
from aril_ros.rollout import RolloutEngine


def answering(victim_file, expert_file):
    from aril_ros.policy import load_policy

    return AnswersOnly(load_policy(victim_file)), load_policy(expert_file)


@pytest.fixture
def swimmer_files(tmp_path, make_policy):
    """A victim that reacts strongly to its observation (scaled random weights) and is its own
    expert, so the objective is exactly the disagreement the attack causes."""
    victim = make_policy("Swimmer-v5", seed=1)
    with torch.no_grad():
        for layer in victim.net[::2]:
            layer.weight.mul_(3.0)
    path = save_policy(victim, tmp_path / "victim.pt")
    return path, path


def objective(adversary_file, victim, expert, mode="sensory"):
    """Mean per-step disagreement of the victim with the expert under the adversary, fixed seeds."""
    from aril_ros.policy import load_policy

    victim, expert = load_policy(victim), load_policy(expert)
    attack = make_attack("aril_a", layout_of("Swimmer-v5"), 0.0, victim, expert, adversary=str(adversary_file),
                         mode=mode)
    engine = RolloutEngine("Swimmer-v5", victim, expert, attack, mode, n_envs=4, horizon=250)
    return engine.rollout(4, seed=123).mean_expert_loss


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["sensory", "physical"])
def test_a_short_training_run_increases_the_objective(mode, swimmer_files, tmp_path):
    victim, expert = swimmer_files
    common = dict(env="Swimmer-v5", mode=mode, eps=0.3, victim=str(victim), expert=str(expert), n_envs=8,
                  rollout=250, seed=3)
    untrained = train_adversary(AdversaryConfig(**common, steps=0, out=str(tmp_path / "a0.pt")),
                                log=lambda *a, **k: None)
    trained = train_adversary(AdversaryConfig(**common, steps=24_000, out=str(tmp_path / "a1.pt")),
                              log=lambda *a, **k: None)
    before, after = objective(untrained, victim, expert, mode), objective(trained, victim, expert, mode)
    assert after > 1.3 * before, (before, after)


def test_an_adversary_of_a_replaced_victim_is_stale_and_retrained(swimmer_files, tmp_path, make_policy):
    """A bundled learner retrained in place must not be judged by the attack trained on the one before it."""
    victim, expert = swimmer_files
    adversary = tmp_path / "adv.pt"
    train_adversary(AdversaryConfig(env="Swimmer-v5", eps=0.2, victim=str(victim), expert=str(expert), steps=0,
                                    out=str(adversary)), log=lambda *a, **k: None)
    assert trained_for(adversary, 0.2, str(victim), "Swimmer-v5")
    assert not trained_for(adversary, 0.3, str(victim), "Swimmer-v5")
    save_policy(make_policy("Swimmer-v5", seed=2), victim)  # the same path, another learner
    assert trained_for(adversary, 0.2) and not trained_for(adversary, 0.2, str(victim), "Swimmer-v5")
    ready_adversary(adversary, str(victim), "Swimmer-v5", "sensory", 0.2, str(expert), 0, False, lambda *a, **k: None)
    assert trained_for(adversary, 0.2, str(victim), "Swimmer-v5")


def test_adversary_files_round_trip_and_refuse_mismatches(swimmer_files, tmp_path):
    victim, expert = swimmer_files
    path = train_adversary(AdversaryConfig(env="Swimmer-v5", eps=0.2, victim=str(victim), expert=str(expert),
                                           steps=0, out=str(tmp_path / "adv.pt")), log=lambda *a, **k: None)
    net = load_adversary(path, "Swimmer-v5", "sensory")
    assert net.meta["provenance"]["victim"] == str(victim) and net.meta["eps"] == 0.2
    assert (net.meta["policy"], net.meta["inputs"]) == ("categorical", "state+actions")
    again = load_adversary(save_adversary(net, tmp_path / "copy.pt"))
    x = torch.randn(5, 8 + 2 + 2)  # the observation, the victim's action, the expert's action
    assert torch.equal(net.distribution(x).logits, again.distribution(x).logits)
    choices = set(net.most_likely(net.distribution(x * 100)).flatten().tolist())
    assert choices <= {-0.2, 0.0, 0.2}  # one of {-eps, 0, +eps} per entry
    with pytest.raises(PolicyFileError, match="trained for Swimmer-v5 \\(sensory\\), not HalfCheetah-v5"):
        load_adversary(path, "HalfCheetah-v5")
    with pytest.raises(PolicyFileError, match="not Swimmer-v5 \\(physical\\)"):
        load_adversary(path, mode="physical")
    with pytest.raises(PolicyFileError, match="not an aril_ros adversary file"):
        load_adversary(victim)  # a policy file is not an adversary
    with pytest.raises(ValueError, match="trained with eps=0.2, not eps=0.1"):
        make_attack("aril_a", layout_of("Swimmer-v5"), 0.1, adversary=str(path))
    with pytest.raises(ValueError, match="needs an adversary file: no bundled one for Hopper-v5"):
        make_attack("aril_a", layout_of("Hopper-v5"), 0.1)
    with pytest.raises(ValueError, match="aril_a queries the victim's actions and the expert's: it needs both"):
        make_attack("aril_a", layout_of("Swimmer-v5"), 0.2, adversary=str(path))  # this one takes their actions
    from aril_ros.policy import resolve_policy

    bundled = make_attack("aril_a", layout_of("Swimmer-v5"), 0.0, resolve_policy("dagger", "Swimmer-v5"),
                          resolve_policy("expert", "Swimmer-v5"), mode="physical")  # by name: the bundled one
    assert bundled.net.meta["provenance"]["victim"] == "dagger" and bundled.eps == bundled.net.eps


def test_learned_attack_is_seeded_and_bounded(swimmer_files, tmp_path):
    victim, expert = swimmer_files
    path = train_adversary(AdversaryConfig(env="Swimmer-v5", eps=0.2, victim=str(victim), expert=str(expert),
                                           steps=0, out=str(tmp_path / "adv.pt")), log=lambda *a, **k: None)
    attack = make_attack("aril_a", layout_of("Swimmer-v5"), 0.2, *answering(victim, expert), adversary=str(path))
    obs = np.random.default_rng(0).normal(size=(6, 8))
    a = attack.perturb(obs, [np.random.default_rng([1, i]) for i in range(6)])
    b = attack.perturb(obs, [np.random.default_rng([1, i]) for i in range(6)])
    np.testing.assert_array_equal(a, b)
    assert np.all(np.abs(a[:, :3]) <= 0.2) and np.all(a[:, 3:] == 0)
    assert set(np.unique(a)) <= {-0.2, 0.0, 0.2}  # categorical: the box's corners, its faces and the centre


def test_a_rescaled_learned_attack_is_the_same_perturbation_scaled(swimmer_files, tmp_path):
    victim, expert = swimmer_files
    path = train_adversary(AdversaryConfig(env="Swimmer-v5", eps=0.2, victim=str(victim), expert=str(expert),
                                           steps=0, out=str(tmp_path / "adv.pt")), log=lambda *a, **k: None)
    obs = np.random.default_rng(0).normal(size=(6, 8))
    own = make_attack("aril_a", layout_of("Swimmer-v5"), 0.2, *answering(victim, expert), adversary=str(path))
    half = make_attack("aril_a", layout_of("Swimmer-v5"), 0.1, *answering(victim, expert), adversary=str(path),
                       rescale=True)
    a = own.perturb(obs, [np.random.default_rng([1, i]) for i in range(6)])
    b = half.perturb(obs, [np.random.default_rng([1, i]) for i in range(6)])
    np.testing.assert_allclose(b, 0.5 * a, rtol=0, atol=1e-15)
    assert half.eps == 0.1 and np.all(np.abs(b) <= 0.1)


@pytest.mark.slow
def test_training_can_start_from_an_adversary_file(swimmer_files, tmp_path):
    victim, expert = swimmer_files
    common = dict(env="Swimmer-v5", eps=0.2, victim=str(victim), expert=str(expert), n_envs=4, rollout=50)
    first = train_adversary(AdversaryConfig(**common, steps=400, seed=1, out=str(tmp_path / "a.pt")),
                            log=lambda *a, **k: None)
    # with a zero learning rate the started-from weights come out unchanged: init:= is what training starts from
    kept = train_adversary(AdversaryConfig(**common, steps=400, seed=2, lr=0.0, init=str(first),
                                           out=str(tmp_path / "b.pt")), log=lambda *a, **k: None)
    fresh = train_adversary(AdversaryConfig(**common, steps=400, seed=2, lr=0.0, out=str(tmp_path / "c.pt")),
                            log=lambda *a, **k: None)
    a, b, c = (load_adversary(p).state_dict() for p in (first, kept, fresh))
    assert all(torch.equal(a[k], b[k]) for k in a) and not torch.equal(a["mean_net.0.weight"], c["mean_net.0.weight"])
    with pytest.raises(ValueError, match="has eps 0.2, width 64, policy categorical and inputs state\\+actions, "
                                         "not eps:=0.1 hidden:=64"):
        train_adversary(AdversaryConfig(**{**common, "eps": 0.1}, steps=0, init=str(first),
                                        out=str(tmp_path / "d.pt")), log=lambda *a, **k: None)


def test_a_training_keeps_snapshots_equal_to_shorter_trainings(swimmer_files, tmp_path):
    """snapshot_every:=400 over 6 updates of 200 steps keeps the states after 2 and 4 updates, each the very weights
    (and the questions counted so far) of a training that stopped there; another training writing the same file drops
    them."""
    victim, expert = swimmer_files
    common = dict(env="Swimmer-v5", eps=0.2, victim=str(victim), expert=str(expert), n_envs=4, rollout=50, seed=1)
    out = tmp_path / "a.pt"
    train_adversary(AdversaryConfig(**common, steps=1200, snapshot_every=400, out=str(out)), log=lambda *a, **k: None)
    kept = snapshots_of(out)
    assert [path.name for path in kept] == ["a-at-400.pt", "a-at-800.pt"]
    for path, steps in zip(kept, (400, 800)):
        shorter = train_adversary(AdversaryConfig(**common, steps=steps, out=str(tmp_path / f"short-{steps}.pt")),
                                  log=lambda *a, **k: None)
        ours, theirs = load_adversary(path), load_adversary(shorter)
        assert all(torch.equal(a, b) for a, b in zip(ours.state_dict().values(), theirs.state_dict().values()))
        made, made_short = ours.meta["provenance"], theirs.meta["provenance"]
        assert made["steps"] == made_short["steps"] == steps and made["queries"] == made_short["queries"]
    train_adversary(AdversaryConfig(**common, steps=200, out=str(out)), log=lambda *a, **k: None)
    assert snapshots_of(out) == []


@pytest.mark.slow
def test_the_states_a_training_keeps_come_back_from_its_sweep_task(swimmer_files, tmp_path, monkeypatch):
    """A training run as a Ray task writes in a scratch folder of its own: the states it keeps come back beside its
    file, as the file does (a relative out:=, as a scorecard gives it), the very weights of a training in this
    process."""
    from pathlib import Path
    victim, expert = swimmer_files
    monkeypatch.chdir(tmp_path)
    cfg = AdversaryConfig(env="Swimmer-v5", eps=0.2, victim=str(victim), expert=str(expert), n_envs=4, rollout=50,
                          seed=1, steps=1200, snapshot_every=400, out="made/a.pt")
    with local_ray():
        ready_adversaries([cfg], True, lambda *a, **k: None, workers=2)
    here = train_adversary(AdversaryConfig(**{**cfg.__dict__, "out": "here/a.pt"}), log=lambda *a, **k: None)
    for ours, theirs in zip(snapshots_of(Path("made/a.pt")), snapshots_of(here), strict=True):
        assert ours.name == theirs.name and all(torch.equal(a, b) for a, b in zip(
            load_adversary(ours).state_dict().values(), load_adversary(theirs).state_dict().values()))
    assert [path.name for path in snapshots_of(here)] == ["a-at-400.pt", "a-at-800.pt"]


def test_query_time_search_applies_the_most_damaging_candidate(swimmer_files, tmp_path):
    victim, expert = swimmer_files
    path = train_adversary(AdversaryConfig(env="Swimmer-v5", eps=0.2, victim=str(victim), expert=str(expert),
                                           steps=0, out=str(tmp_path / "adv.pt")), log=lambda *a, **k: None)
    black_box, labeller = answering(victim, expert)
    layout = layout_of("Swimmer-v5")
    obs = np.random.default_rng(0).normal(size=(40, 8))
    rngs = lambda: [np.random.default_rng([2, i]) for i in range(40)]  # noqa: E731
    searched = make_attack("aril_a", layout, 0.2, black_box, labeller, adversary=str(path), search=8)
    delta = searched.perturb(obs, rngs())
    assert searched.queries_per_step == 1 + 9  # its input action, then 8 draws and the likeliest
    assert np.all(np.abs(delta[:, :3]) <= 0.2) and np.all(delta[:, 3:] == 0)
    loss = lambda d: ((black_box.act(obs + d) - labeller.act(obs)) ** 2).sum(1)  # noqa: E731
    likeliest = LearnedAttack(layout, searched.net, stochastic=False, victim=black_box, expert=labeller)
    drawn = LearnedAttack(layout, searched.net, victim=black_box, expert=labeller)
    assert np.all(loss(delta) >= loss(likeliest.perturb(obs, rngs())))  # the likeliest is always a candidate
    assert loss(delta).mean() > loss(drawn.perturb(obs, rngs())).mean()


def test_a_gaussian_state_only_adversary_asks_no_queries(swimmer_files, tmp_path):
    """The adversaries made before the categorical policy: a Gaussian on the state alone, no victim needed."""
    victim, expert = swimmer_files
    path = train_adversary(AdversaryConfig(env="Swimmer-v5", eps=0.2, victim=str(victim), expert=str(expert),
                                           policy="gaussian", inputs="state", steps=0, out=str(tmp_path / "adv.pt")),
                           log=lambda *a, **k: None)
    attack = make_attack("aril_a", layout_of("Swimmer-v5"), 0.0, adversary=str(path))  # no victim, no expert
    obs = np.random.default_rng(0).normal(size=(3, 8))
    delta = attack.perturb(obs, [np.random.default_rng(i) for i in range(3)])
    assert attack.queries == 0 and np.all(np.abs(delta) <= 0.2) and len(np.unique(delta[:, :3])) == 9


class EndingSims:
    """Simulators whose first one ends its episode early (a termination, as a fallen Ant's) at the step given,
    keeping the observation it ended in."""

    def __init__(self, sims, end_at: int):
        self.sims, self.end_at, self.steps, self.ended_in = sims, end_at, 0, None

    def __len__(self):
        return len(self.sims)

    def __getattr__(self, name):
        return getattr(self.sims, name)

    def step(self, action, rows):
        obs, reward, terminated, truncated = self.sims.step(action, rows)
        self.steps += 1
        if self.steps == self.end_at:
            terminated = terminated.copy()
            terminated[0], self.ended_in = True, obs[0].copy()
        return obs, reward, terminated, truncated


@pytest.mark.parametrize("terminal", ["bootstrap", "held"])
def test_an_early_end_is_worth_what_terminal_says(terminal, swimmer_files, make_policy, tmp_path):
    """terminal:=nothing gives the adversary nothing after a termination (toppling the victim ends its reward);
    bootstrap adds the value of the state it ended in, held that state's disagreement at every later step."""
    from aril_ros import adversary as adv
    from aril_ros.policy import load_policy
    from aril_ros.rollout import SimBatch
    from aril_ros.step import disagreement

    victim, expert = load_policy(swimmer_files[0]), make_policy("Swimmer-v5", seed=5)
    rollouts = {}
    for setting in ("nothing", terminal):
        cfg = AdversaryConfig(env="Swimmer-v5", eps=0.2, victim=str(swimmer_files[0]), n_envs=2, rollout=6,
                              warmup=5, gamma=0.9, terminal=setting)
        sims, resets = EndingSims(SimBatch(cfg.env, cfg.n_envs), end_at=6), adv.EnvSeeds(100)
        net = adv.initial_adversary(cfg, *adv.input_scaling(cfg, sims, victim, expert, resets))
        sims.steps = 0  # the warm-up's steps do not count: the collection's sixth step ends the first simulator
        collector = adv.Collector(cfg, sims, resets, net, adv.ValuePlay(cfg, sims, net, victim), victim, expert,
                                  torch.Generator().manual_seed(0))
        rollouts[setting] = collector.collect(), collector, sims
    (plain, _, _), (valued, collector, sims) = rollouts["nothing"], rollouts[terminal]
    assert plain.done[-1, 0] == valued.done[-1, 0] == 1.0
    assert torch.equal(plain.reward[:, 1], valued.reward[:, 1]) and torch.equal(plain.reward[:-1], valued.reward[:-1])
    scale, ended_in = collector.return_scale.std, sims.ended_in[None]
    if terminal == "held":  # gamma / (1 - gamma) = 9 steps' worth of the state's disagreement
        worth = 9.0 * disagreement(victim.act(ended_in), expert.act(ended_in))[0] / scale
    else:
        worth = 0.9 * collector.value_of(ended_in, scale, [0])[0].item()
    assert worth > 0 and valued.reward[-1, 0].item() == pytest.approx(plain.reward[-1, 0].item() + worth, rel=1e-5)
    with pytest.raises(ValueError, match="terminal:=held .* needs gamma:= < 1"):
        train_adversary(AdversaryConfig(env="Swimmer-v5", eps=0.2, victim=str(swimmer_files[0]), gamma=1.0,
                                        terminal="held", steps=0, out=str(tmp_path / "a.pt")))


class RecordingSims(EndingSims):
    """Simulators that keep the env's rewards of the last step (and end no episode early)."""

    def __init__(self, sims):
        super().__init__(sims, end_at=-1)
        self.rewards = None

    def step(self, action, rows):
        obs, self.rewards, terminated, truncated = super().step(action, rows)
        return obs, self.rewards, terminated, truncated


def test_the_return_objective_rewards_the_victims_lost_reward(swimmer_files, make_policy):
    """objective:=return: the adversary's reward is minus the victim's reward from the env (in units of the return's
    spread), with no exact disagreement part in its value; the paper's objective is the disagreement."""
    from aril_ros import adversary as adv
    from aril_ros.policy import load_policy
    from aril_ros.rollout import SimBatch

    victim, expert = load_policy(swimmer_files[0]), make_policy("Swimmer-v5", seed=5)
    cfg = AdversaryConfig(env="Swimmer-v5", eps=0.2, victim=str(swimmer_files[0]), n_envs=2, rollout=6, warmup=5,
                          objective="return")
    sims, resets = RecordingSims(SimBatch(cfg.env, cfg.n_envs)), adv.EnvSeeds(100)
    net = adv.initial_adversary(cfg, *adv.input_scaling(cfg, sims, victim, expert, resets))
    collector = adv.Collector(cfg, sims, resets, net, adv.ValuePlay(cfg, sims, net, victim), victim, expert,
                              torch.Generator().manual_seed(0))
    rollout = collector.collect()
    assert torch.equal(rollout.base, torch.zeros_like(rollout.base))
    expected = -sims.rewards / collector.return_scale.std
    assert np.abs(sims.rewards).min() > 0 and rollout.reward[-1].numpy() == pytest.approx(expected, rel=1e-5)


def test_the_directed_actor_finds_the_corner_that_moves_the_action_along_the_direction():
    """For a victim linear in the zero-order entries the first-order answer is exact: eps * sign(W^T d)."""
    from aril_ros.adversary_net import pushes

    rng = np.random.default_rng(0)
    weights = rng.normal(size=(2, 3))  # action = W @ (the three zero-order entries), the rest ignored
    asked = []

    def ask(obs):
        asked.append(len(obs))
        return obs[:, :3] @ weights.T

    obs, directions = rng.normal(size=(5, 8)), rng.normal(size=(5, 4, 2))
    got = pushes(ask, obs, directions, 0.2, 3)
    np.testing.assert_array_equal(got, 0.2 * np.sign(np.einsum("ap,nka->nkp", weights, directions)))
    assert asked == [5 * 6]  # 2 questions per zero-order entry and row, in one batch
    corners = 0.2 * np.array(np.meshgrid(*[[-1, 1]] * 3)).reshape(3, -1).T  # every corner of the box
    best = np.einsum("ap,cp,nka->nkc", weights, corners, directions).max(-1)
    np.testing.assert_allclose(np.einsum("ap,nkp,nka->nk", weights, got, directions), best)


def test_a_directed_adversary_trains_and_attacks_through_answers_alone(swimmer_files, make_policy, tmp_path):
    """policy:=directed: a direction in action space per step, its perturbation the actor's corner, every question
    to the victim an act(); at evaluation 1 (its input) + 2 per zero-order entry a step, + the search's."""
    victim, _ = swimmer_files
    expert_file = save_policy(make_policy("Swimmer-v5", seed=5), tmp_path / "expert.pt")
    path = train_adversary(AdversaryConfig(env="Swimmer-v5", eps=0.2, victim=str(victim), expert=str(expert_file),
                                           policy="directed", steps=512, n_envs=2, rollout=128, warmup=5,
                                           out=str(tmp_path / "adv.pt")), log=lambda *a, **k: None)
    net = load_adversary(path)
    assert net.directed and net.meta["provenance"]["queries"] > 512 * (1 + 6)
    black_box, labeller = answering(victim, expert_file)
    obs = np.random.default_rng(0).normal(size=(6, 8))
    rngs = lambda: [np.random.default_rng([1, i]) for i in range(6)]  # noqa: E731
    for search, asked in ((0, 1 + 6), (4, 1 + 6 + 5)):
        attack = make_attack("aril_a", layout_of("Swimmer-v5"), 0.2, black_box, labeller, adversary=str(path),
                             search=search)
        delta = attack.perturb(obs, rngs())
        np.testing.assert_array_equal(delta, attack.perturb(obs, rngs()))
        assert attack.queries_per_step == asked
        assert set(np.unique(delta[:, :3])) <= {-0.2, 0.0, 0.2} and np.all(delta[:, 3:] == 0)
    with pytest.raises(ValueError, match="pushes"):
        net.delta(torch.zeros(1, 2))
