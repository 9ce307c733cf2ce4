import json
import subprocess
import sys

import numpy as np
import pytest

from aril_ros.args import ArgumentError, parse_args
from aril_ros.cli import EvalConfig, main
from aril_ros.envs import make_gym_env
from aril_ros.experts import export_sac_actor
from aril_ros.policy import PolicyFileError, resolve_policy, save_policy
from aril_ros.registry import PAPER_ENVS, bundled_path


def test_exported_sac_actor_acts_exactly_like_sb3():
    from stable_baselines3 import SAC

    env = make_gym_env("HalfCheetah-v5")
    model = SAC("MlpPolicy", env, seed=0, device="cpu", learning_starts=50, batch_size=32,
                policy_kwargs={"net_arch": [32, 32]})
    model.learn(120)  # a few gradient steps so the weights are not the initial ones
    policy = export_sac_actor(model, "HalfCheetah-v5", {"test": True})
    obs = np.random.default_rng(0).normal(size=(20, 17)).astype(np.float32)
    theirs, _ = model.predict(obs, deterministic=True)
    np.testing.assert_allclose(policy.act(obs), theirs, atol=1e-6)
    env.close()


def test_exported_ppo_actor_acts_exactly_like_sb3():
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from aril_ros.experts import export_ppo_actor

    env = VecNormalize(DummyVecEnv([lambda: make_gym_env("Swimmer-v5")]))
    model = PPO("MlpPolicy", env, seed=0, device="cpu", n_steps=64, batch_size=32, n_epochs=1)
    model.learn(128)  # one update, and normalisation statistics that are not the initial ones
    policy = export_ppo_actor(model, env, "Swimmer-v5", {"test": True})
    raw = np.random.default_rng(0).normal(scale=2, size=(20, 8))
    theirs, _ = model.predict(env.normalize_obs(raw), deterministic=True)
    np.testing.assert_allclose(policy.act(raw), theirs, atol=1e-5)
    assert policy.meta.squash == "clip" and policy.meta.obs_clip == 10.0


@pytest.mark.parametrize("env_id", PAPER_ENVS)
def test_bundled_experts_load_with_provenance(env_id):
    path = bundled_path("expert", env_id)
    if not path.exists():
        pytest.fail(f"bundled expert missing: {path}")
    expert = resolve_policy("expert", env_id)
    prov = expert.meta.provenance
    assert prov["command"].startswith("aril train-expert") and prov["train_seconds"] > 0
    assert len(expert.meta.hidden) == 2  # the paper: two hidden layers


def test_bundled_is_the_default_bundled_policy():
    np.testing.assert_array_equal(resolve_policy("bundled", "Swimmer-v5").act(np.ones(8)),
                                  resolve_policy("dagger", "Swimmer-v5").act(np.ones(8)))


def test_resolve_policy_errors():
    with pytest.raises(PolicyFileError, match="no expert for Hopper-v5 .*aril train-expert env:=Hopper-v5"):
        resolve_policy("expert", "Hopper-v5")
    with pytest.raises(PolicyFileError, match="neither a bundled policy name"):
        resolve_policy("dagger_typo", "Swimmer-v5")


def test_key_value_arguments():
    cfg = parse_args(EvalConfig, ["env:=Ant-v5", "eps:=0.2", "episodes:=3"])
    assert (cfg.env, cfg.eps, cfg.episodes, cfg.mode) == ("Ant-v5", 0.2, 3, "clean")
    with pytest.raises(ArgumentError, match="unknown argument 'epz'"):
        parse_args(EvalConfig, ["epz:=0.1"])
    with pytest.raises(ArgumentError, match="key:=value"):
        parse_args(EvalConfig, ["--eps=0.1"])
    with pytest.raises(ArgumentError, match="eps:= takes float"):
        parse_args(EvalConfig, ["eps:=big"])


def test_eval_prints_progress_and_a_json_summary(tmp_path, make_policy, capsys):
    path = save_policy(make_policy("Swimmer-v5"), tmp_path / "p.pt")
    code = main(["eval", "env:=Swimmer-v5", f"policy:={path}", f"expert:={path}", "mode:=sensory",
                 "attack:=random", "eps:=0.1", "episodes:=3", "horizon:=50"])
    out, err = capsys.readouterr()
    assert code == 0
    summary = json.loads(out.strip().splitlines()[-1])
    for key in ("env", "policy", "mode", "attack", "eps", "episodes", "mean_return", "std_return",
                "mean_expert_loss"):
        assert key in summary
    assert summary["steps"] == 150 and summary["mean_expert_loss"] > 0  # it saw perturbed observations
    assert err.count("episode ") == 3 and "max|delta| 0.09" in err
    assert main(["eval", "env:=Swimmer-v5", f"policy:={path}", f"expert:={path}", "horizon:=50"]) == 0
    clean = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert clean["mean_expert_loss"] == 0.0 and clean["attack"] == "none"  # its own expert, unattacked


def test_eval_errors_are_one_clear_line(capsys):
    assert main(["eval", "env:=CartPole-v1"]) == 2
    assert "not a gymnasium MuJoCo environment" in capsys.readouterr().err
    assert main(["eval", "mode:=clean", "attack:=random"]) == 2
    assert "mode:=clean runs no attack" in capsys.readouterr().err


@pytest.mark.slow
def test_a_non_mujoco_id_is_refused_in_a_fresh_process():
    # nothing else imported gymnasium's MuJoCo package in that process
    out = subprocess.run([sys.executable, "-m", "aril_ros", "eval", "env:=CartPole-v1"], capture_output=True, text=True)
    assert out.returncode == 2 and "not a gymnasium MuJoCo environment" in out.stderr, out.stderr


@pytest.mark.slow
def test_help_and_module_entry_point():
    out = subprocess.run([sys.executable, "-m", "aril_ros", "eval", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "mode:=" in out.stdout and "episodes:=" in out.stdout
    out = subprocess.run([sys.executable, "-m", "aril_ros", "frobnicate"], capture_output=True, text=True)
    assert out.returncode == 2 and "train-expert" in out.stdout


@pytest.mark.slow
def test_train_expert_resumes_from_a_checkpoint(tmp_path):
    from aril_ros.experts import ExpertConfig, train_expert
    from aril_ros.policy import load_policy

    quiet = dict(log=lambda *a, **k: None)
    common = dict(env="Swimmer-v5", algo="ppo", eval_every=2048, eval_episodes=1, out=str(tmp_path / "e.pt"))
    train_expert(ExpertConfig(steps=2048, hidden=16, checkpoint=str(tmp_path / "ckpt"), **common), **quiet)
    assert load_policy(tmp_path / "e.pt").meta.hidden == [16, 16]
    state = json.loads((tmp_path / "ckpt" / "state.json").read_text())
    assert state["steps"] == 2048 and state["algo"] == "ppo"
    train_expert(ExpertConfig(steps=4096, resume=str(tmp_path / "ckpt"), checkpoint=str(tmp_path / "ckpt"),
                              **common), **quiet)
    assert json.loads((tmp_path / "ckpt" / "state.json").read_text())["steps"] == 4096
    assert len(json.loads((tmp_path / "ckpt" / "state.json").read_text())["commands"]) == 2
    prov = load_policy(tmp_path / "e.pt").meta.provenance
    assert prov["steps"] in (2048, 4096)
    assert load_policy(tmp_path / "e.pt").meta.hidden == [16, 16]  # hidden:=0: the resumed model's own
    with pytest.raises(ValueError, match=r"hidden layers \[16, 16\], not hidden:=32"):
        train_expert(ExpertConfig(steps=6144, hidden=32, resume=str(tmp_path / "ckpt"), **common), **quiet)
    with pytest.raises(ValueError, match="holds a ppo run on Swimmer-v5"):
        train_expert(ExpertConfig(env="Swimmer-v5", algo="sac", resume=str(tmp_path / "ckpt")), **quiet)
