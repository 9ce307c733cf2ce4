import numpy as np
import pytest
import torch

from aril_ros.adversary import (AdversaryConfig, load_adversary, ready_adversary, save_adversary, train_adversary,
                                trained_for)
from aril_ros.attacks import LearnedAttack, make_attack
from tests.conftest import AnswersOnly
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
