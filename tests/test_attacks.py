import numpy as np
import pytest

from aril_ros.attacks import FGSM, make_attack
from tests.conftest import AnswersOnly
from aril_ros.envs import MujocoSim, layout_of


def true_states(env_id, n=64, seed=0):
    """Observations from real states: reset with different seeds and random actions."""
    sim = MujocoSim(env_id)
    rng = np.random.default_rng(seed)
    states = []
    for i in range(n):
        sim.reset(seed=seed + i)
        for _ in range(int(rng.integers(0, 30))):
            sim.step(rng.uniform(-1, 1, sim.layout.act_dim))
        states.append(sim.observe())
    sim.close()
    return np.array(states)


@pytest.fixture
def victim_expert(make_policy):
    return make_policy("HalfCheetah-v5", seed=1, hidden=(64, 64)), make_policy("HalfCheetah-v5", seed=2)


def one_step_loss(victim, expert, obs, delta):
    return ((victim.act(obs + delta) - expert.act(obs)) ** 2).sum(axis=1)


def test_fgsm_sign_direction_increases_the_one_step_loss(victim_expert):
    victim, expert = victim_expert
    obs = true_states("HalfCheetah-v5")
    delta = make_attack("fgsm", layout_of("HalfCheetah-v5"), 0.01, victim, expert).perturb(obs, [None] * len(obs))
    before = one_step_loss(victim, expert, obs, 0 * delta)
    after = one_step_loss(victim, expert, obs, delta)
    assert (after > before).mean() > 0.95
    flipped = one_step_loss(victim, expert, obs, -delta)  # the opposite sign lowers it instead
    assert (after > flipped).mean() > 0.95


def test_fgsm_k_finds_a_larger_loss_than_fgsm(victim_expert):
    victim, expert = victim_expert
    obs = true_states("HalfCheetah-v5", seed=100)
    layout = layout_of("HalfCheetah-v5")
    fgsm = make_attack("fgsm", layout, 0.2, victim, expert).perturb(obs, [None] * len(obs))
    fgsm_k = make_attack("fgsm_k", layout, 0.2, victim, expert, steps=10).perturb(obs, [None] * len(obs))
    assert np.all(np.abs(fgsm_k) <= 0.2)
    assert one_step_loss(victim, expert, obs, fgsm_k).mean() >= one_step_loss(victim, expert, obs, fgsm).mean()


def test_fgsm_is_white_box_and_its_gradient_batch_invariant(victim_expert):
    victim, expert = victim_expert
    layout = layout_of("HalfCheetah-v5")
    with pytest.raises(ValueError, match="white-box"):
        make_attack("fgsm", layout, 0.1)
    with pytest.raises(ValueError, match="steps must be"):
        FGSM(layout, 0.1, victim, expert, steps=0)
    obs = true_states("HalfCheetah-v5", n=70)
    label = expert.act(obs)
    whole, actions = victim.loss_gradient(obs, label)
    np.testing.assert_array_equal(whole[5], victim.loss_gradient(obs[5:6], label[5:6])[0][0])
    np.testing.assert_array_equal(whole[:7], victim.loss_gradient(obs[:7], label[:7])[0])
    np.testing.assert_array_equal(actions, victim.act(obs))  # FGSM^k takes its iterates' losses from them


def test_spsa_is_black_box_bounded_and_near_fgsm(victim_expert):
    victim, expert = victim_expert
    layout = layout_of("HalfCheetah-v5")
    obs = true_states("HalfCheetah-v5", seed=200)
    rngs = lambda: [np.random.default_rng([3, i]) for i in range(len(obs))]  # noqa: E731
    with pytest.raises(ValueError, match="spsa queries the victim's actions and the expert's"):
        make_attack("spsa", layout, 0.2)
    spsa = make_attack("spsa", layout, 0.2, AnswersOnly(victim), expert)
    delta = spsa.perturb(obs, rngs())
    np.testing.assert_array_equal(delta, spsa.perturb(obs, rngs()))  # seeded by the episodes' rngs
    assert np.all(np.abs(delta) <= 0.2) and np.all(delta[:, ~layout.zero_order_mask] == 0)
    assert spsa.queries_per_step == 1 + 5 * (2 * 8 + 1)
    fgsm = make_attack("fgsm", layout, 0.2, victim, expert).perturb(obs, [None] * len(obs))
    random = make_attack("random", layout, 0.2).perturb(obs, rngs())
    gain = lambda d: (one_step_loss(victim, expert, obs, d) - one_step_loss(victim, expert, obs, 0 * d)).mean()  # noqa: E731
    assert gain(delta) > 0.8 * gain(fgsm) and gain(delta) > 3 * gain(random), (gain(delta), gain(fgsm), gain(random))


@pytest.mark.parametrize("env_id, eps", [("HalfCheetah-v5", 0.04), ("Ant-v5", 0.03)])
def test_fd_fgsm_finds_white_box_fgsms_perturbation_from_answers_alone(env_id, eps):
    """On the bundled DAgger learner (its float32 net, the observation clip and the action bounds included), the
    finite differences of its answers give the sign white-box FGSM takes from its weights, entry for entry, nearly
    everywhere (where they differ the slope is flat), at 2 questions per perturbed entry and step."""
    from aril_ros.policy import resolve_policy

    layout = layout_of(env_id)
    victim, expert = resolve_policy("dagger", env_id), resolve_policy("expert", env_id)
    obs = true_states(env_id, n=200, seed=300)
    with pytest.raises(ValueError, match="fd_fgsm queries the victim's actions and the expert's"):
        make_attack("fd_fgsm", layout, eps)
    attack = make_attack("fd_fgsm", layout, eps, AnswersOnly(victim), expert)
    delta = attack.perturb(obs, [None] * len(obs))
    assert np.all(np.abs(delta) <= eps) and np.all(delta[:, ~layout.zero_order_mask] == 0)
    assert attack.queries_per_step == 2 * layout.n_position
    fgsm = make_attack("fgsm", layout, eps, victim, expert).perturb(obs, [None] * len(obs))
    assert (delta == fgsm)[:, :layout.n_position].mean() > 0.99  # 1.0 on this machine's 200 states of both envs
    assert (delta == fgsm).all(axis=1).mean() > 0.95  # whole perturbations, not only entries
    iterated = make_attack("fd_fgsm", layout, eps, AnswersOnly(victim), expert, steps=3)
    stepped = iterated.perturb(obs, [None] * len(obs))
    assert iterated.queries_per_step == 3 * (2 * layout.n_position + 1) + 1
    assert np.all(np.abs(stepped) <= eps)
    # each row keeps its best iterate, so it takes at least the first iterate's loss (a step of eps / 3)
    first = make_attack("fd_fgsm", layout, eps / 3, AnswersOnly(victim), expert).perturb(obs, [None] * len(obs))
    assert np.all(one_step_loss(victim, expert, obs, stepped) >= one_step_loss(victim, expert, obs, first) - 1e-12)


@pytest.mark.parametrize("env_id, eps", [("HalfCheetah-v5", 0.04), ("Ant-v5", 0.03), ("Swimmer-v5", 0.3)])
def test_random_noise_is_each_episodes_uniform_draws(env_id, eps):
    """The noise of row i is ``rng_i.uniform(-eps, eps)`` on the zero-order entries, bit for bit (the engine and the
    graph's attacker draw it so; every table's random row and DR's training data rest on it), and zero elsewhere."""
    layout = layout_of(env_id)
    obs = np.zeros((5, layout.obs_dim))
    delta = make_attack("random", layout, eps).perturb(obs, [np.random.default_rng([7, i]) for i in range(5)])
    for i, row in enumerate(delta):
        expected = np.random.default_rng([7, i]).uniform(-eps, eps, layout.n_position)
        np.testing.assert_array_equal(row[:layout.n_position], expected)
        assert np.all(row[layout.n_position:] == 0)
