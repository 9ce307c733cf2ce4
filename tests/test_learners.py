import numpy as np
import pytest

from aril_ros.dataset import DaggerDataset
from aril_ros.learners import BCConfig, fit_policy, train_bc
from aril_ros.policy import load_policy, save_policy
from aril_ros.rollout import RolloutEngine


def demos(make_policy, episodes=3, horizon=100):
    expert = make_policy("Swimmer-v5", seed=7)
    return expert, RolloutEngine("Swimmer-v5", expert, expert, n_envs=2, horizon=horizon).rollout(episodes, seed=1)


def test_dataset_from_trajectories_keeps_episode_order(make_policy):
    _, traj = demos(make_policy)
    data = DaggerDataset.from_trajectories(traj)
    assert len(data) == traj.length.sum() == 300
    np.testing.assert_array_equal(data.episode, np.repeat([0, 1, 2], 100))
    np.testing.assert_array_equal(data.obs[100:200], traj.obs[1, :100])
    both = DaggerDataset.concatenate([data, data])
    assert len(both) == 600 and both.source[0] == "inprocess:seed=1"
    np.testing.assert_array_equal(both.expert_action[300:], data.expert_action)


def test_fit_policy_is_seeded_and_imitates(make_policy):
    expert, traj = demos(make_policy)
    data = DaggerDataset.from_trajectories(traj)
    a = fit_policy(data, "Swimmer-v5", hidden=32, epochs=40, seed=3)
    b = fit_policy(data, "Swimmer-v5", hidden=32, epochs=40, seed=3)
    np.testing.assert_array_equal(a.act(data.obs), b.act(data.obs))
    untrained = fit_policy(data, "Swimmer-v5", hidden=32, epochs=0, seed=3)
    error = lambda p: ((p.act(data.obs) - data.expert_action) ** 2).sum(1).mean()  # noqa: E731
    assert error(a) < 0.2 * error(untrained)


@pytest.mark.slow
def test_train_bc_writes_a_policy_with_provenance(tmp_path, make_policy):
    expert_file = save_policy(make_policy("Swimmer-v5", seed=7), tmp_path / "expert.pt")
    out = train_bc(BCConfig(env="Swimmer-v5", expert=str(expert_file), episodes=2, epochs=2,
                            out=str(tmp_path / "bc.pt")), log=lambda *a, **k: None)
    policy = load_policy(out, "Swimmer-v5")
    prov = policy.meta.provenance
    assert prov["algorithm"] == "behaviour cloning" and prov["samples"] == 2000 and prov["train_seconds"] > 0
    assert prov["command"].startswith("aril train-bc env:=Swimmer-v5")
