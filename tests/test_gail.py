import numpy as np
import pytest
import torch

from aril_ros.envs import make_gym_env
from aril_ros.gail import DiscriminatorReward, Discriminator, GailConfig, train_gail
from aril_ros.policy import load_policy


def test_the_wrapper_pays_the_discriminators_reward_and_keeps_the_pairs():
    rng = np.random.default_rng(0)
    disc = Discriminator(rng.standard_normal((50, 8)), rng.uniform(-1, 1, (50, 2)), hidden=8)
    env = DiscriminatorReward(make_gym_env("Swimmer-v5"), disc)
    obs, _ = env.reset(seed=0)
    action = np.array([0.5, -0.5])
    _, reward, _, _, info = env.step(action)
    assert reward == disc.reward(obs, action) and reward > 0  # softplus of the logit
    assert "env_reward" in info and info["env_reward"] != reward
    np.testing.assert_array_equal(env.pairs[0][0], obs)
    env.close()


@pytest.mark.slow
def test_a_short_gail_run_writes_a_policy_and_its_discriminator_learns(tmp_path):
    lines = []
    out = train_gail(GailConfig(env="Swimmer-v5", steps=4096, hidden=32, eval_every=2048, eval_episodes=1, demos=1,
                                out=str(tmp_path / "gail.pt")), log=lambda m, **k: lines.append(m))
    policy = load_policy(out, "Swimmer-v5")
    assert policy.meta.hidden == [32, 32]
    assert policy.meta.provenance["algorithm"].startswith("GAIL")
    assert policy.meta.provenance["command"].startswith("aril train-gail env:=Swimmer-v5")
    losses = [float(line.rsplit("disc loss", 1)[1]) for line in lines if "disc loss" in line]
    assert len(losses) == 2 and losses[-1] < np.log(2)  # better than a coin once trained on a rollout


def test_entries_the_demonstrations_never_move_keep_unit_scale():
    obs = np.random.default_rng(0).normal(size=(50, 4))
    obs[:, 2] = 0.0  # e.g. Ant's contact force on a body that never touches
    disc = Discriminator(obs, np.ones((50, 2)), hidden=8)
    assert disc.std[2] == 1.0 and disc.std[4] == 1.0 and disc.std[5] == 1.0
    assert torch.allclose(disc.std[[0, 1, 3]], torch.as_tensor(obs[:, [0, 1, 3]].std(0) + 1e-3, dtype=torch.float32))
