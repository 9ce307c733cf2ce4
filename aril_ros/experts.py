"""Expert training (stable-baselines3 SAC or PPO) and the bundled policy files.

Experts are trained with stable-baselines3 and the rl-baselines3-zoo MuJoCo settings: SAC
(``learning_starts=10000``, two hidden layers of 256) or PPO (two hidden layers of 64, observation
and reward normalisation), ``gamma=0.9999`` for Swimmer. The actor is exported into the aril_ros
policy format (see :mod:`aril_ros.policy`): SAC's deterministic action ``tanh(mu(s))`` scaled into
the action bounds, or PPO's clipped mean with the normaliser's statistics, is exactly what
:class:`MLPPolicy` computes, so the exported file needs neither SB3 nor the training code. During training the exported actor is
evaluated on the rollout engine every ``eval_every`` steps and the best one is kept.

Bundled experts live where :func:`aril_ros.registry.bundled_path` says (``aril_ros/data/expert/``); a user's
go to their data folder (:func:`aril_ros.registry.user_path`) unless ``out:=`` says otherwise.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from . import seeds
from .args import arg
from .envs import layout_of, make_gym_env
from .policy import MLPPolicy, meta_for_env, save_policy
from .provenance import stamp
from .registry import DEFAULT_ENV, shadowed_by_bundled, user_path

# rl-baselines3-zoo's tuned settings for the MuJoCo envs (hyperparams/sac.yml, ppo.yml).
HYPERPARAMETERS = {
    "sac": (dict(learning_starts=10_000, batch_size=256, learning_rate=3e-4, gamma=0.99, tau=0.005),
            {"Swimmer-v5": dict(gamma=0.9999)}),
    "ppo": (dict(n_steps=2048, batch_size=64, n_epochs=10, learning_rate=3e-4, gamma=0.99),  # + VecNormalize
            {"Swimmer-v5": dict(gamma=0.9999)}),
}


def _linears(module) -> list[torch.nn.Linear]:
    return [m for m in module if isinstance(m, torch.nn.Linear)]


def _copy_into(meta, linears) -> MLPPolicy:
    policy = MLPPolicy(meta)
    with torch.no_grad():
        for ours, theirs in zip(_linears(policy.net), linears):
            ours.weight.copy_(theirs.weight)
            ours.bias.copy_(theirs.bias)
    return policy.eval()


def export_sac_actor(model, env_id: str, provenance: dict) -> MLPPolicy:
    """An SB3 SAC actor (latent_pi: Linear-ReLU-Linear-ReLU, mu: Linear; tanh into the bounds)."""
    hidden = _linears(model.policy.actor.latent_pi)
    meta = meta_for_env(env_id, hidden=[m.out_features for m in hidden], activation="relu", squash="tanh",
                        provenance=provenance)
    return _copy_into(meta, hidden + [model.policy.actor.mu])


def export_ppo_actor(model, normalizer, env_id: str, provenance: dict) -> MLPPolicy:
    """An SB3 PPO actor (policy_net: Linear-Tanh-Linear-Tanh, action_net: Linear; clipped to the
    bounds) with its VecNormalize observation statistics folded into the policy file."""
    hidden = _linears(model.policy.mlp_extractor.policy_net)
    rms = normalizer.obs_rms
    meta = meta_for_env(env_id, hidden=[m.out_features for m in hidden], activation="tanh", squash="clip",
                        obs_mean=rms.mean.tolist(), obs_std=np.sqrt(rms.var + normalizer.epsilon).tolist(),
                        obs_clip=float(normalizer.clip_obs), provenance=provenance)
    return _copy_into(meta, hidden + [model.policy.action_net])


@dataclass
class ExpertConfig:
    """Arguments of ``aril train-expert``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    algo: str = arg("sac", "sac (off-policy, sample-efficient) or ppo (on-policy, cheap per step)")
    steps: int = arg(300_000, "environment steps of training", low=1, high=10**9)
    seed: int = arg(0, "seed of the algorithm and of its env", low=0, high=2**31 - 1)
    hidden: int = arg(0, "width of the actor's and the critic's two hidden layers (0: stable-baselines3's default, "
                         "256 for sac and 64 for ppo)", low=0, high=4096)
    eval_every: int = arg(25_000, "evaluate (and keep if best) the exported actor every this many steps",
                          low=1, high=10**9)
    eval_episodes: int = arg(5, f"deterministic episodes per evaluation (env seeds {seeds.SELECTION}...)",
                             low=1, high=100_000)
    out: str = arg("", "where to write the expert (default: expert/<env>.pt in the user data folder, $ARIL_DATA, "
                       "by default ~/.local/share/aril_ros; then expert:=expert finds it where none is bundled)")
    threads: int = arg(1, "torch threads (1 lets two trainings share a 2-core machine)", low=1, high=256)
    checkpoint: str = arg("", "a folder to save the training state to at every evaluation (resume:= takes it)")
    keep_buffer: bool = arg(False, "sac: save the replay buffer with the checkpoint too (large; same-machine resumes)")
    resume: str = arg("", "continue from a checkpoint folder up to steps:= in all (without its replay buffer, "
                          "SAC refills one from the resumed policy)")


def train_expert(cfg: ExpertConfig, log=print, wrap_env=None, on_rollout_end=None, label: str = "train-expert",
                 made_by: dict | None = None, provenance: dict | None = None, status=lambda: "") -> Path:
    """Train on ``cfg.env``, keep the best exported actor by evaluation, write it, return its path.

    Learners built on the same loop (GAIL) pass ``wrap_env`` (applied to the gymnasium env, e.g. to
    swap the reward), ``on_rollout_end`` (called after each PPO rollout), their ``label``, the
    ``made_by`` (the :func:`aril_ros.provenance.stamp` of their own command and settings), extra ``provenance``
    and a ``status()`` text for the evaluation lines."""
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from .rollout import RolloutEngine

    if cfg.algo not in HYPERPARAMETERS:
        raise ValueError(f"algo:= must be one of {', '.join(HYPERPARAMETERS)}, got {cfg.algo!r}")
    torch.set_num_threads(cfg.threads)
    layout_of(cfg.env)  # fail fast on ids that are not MuJoCo envs
    out = Path(cfg.out) if cfg.out else user_path("expert", cfg.env)
    defaults, per_env = HYPERPARAMETERS[cfg.algo]
    hyper = {**defaults, **per_env.get(cfg.env, {})}
    if cfg.hidden:
        hyper["policy_kwargs"] = {"net_arch": [cfg.hidden, cfg.hidden]}
    made_by = made_by or stamp("aril train-expert", cfg)
    command = made_by["command"]
    wrap_env = wrap_env or (lambda env: env)
    resume = Path(cfg.resume) if cfg.resume else None
    state = json.loads((resume / "state.json").read_text()) if resume else {}
    if state and (state["env"], state["algo"]) != (cfg.env, cfg.algo):
        raise ValueError(f"{resume} holds a {state['algo']} run on {state['env']}, not {cfg.algo} on {cfg.env}")
    if cfg.algo == "sac":
        env = wrap_env(make_gym_env(cfg.env))
        if resume:
            model = SAC.load(resume / "model.zip", env=env, device="cpu")
            if (resume / "replay_buffer.pkl").exists():
                model.load_replay_buffer(resume / "replay_buffer.pkl")
        else:
            model = SAC("MlpPolicy", env, seed=cfg.seed, device="cpu", verbose=0, **hyper)
        export = lambda provenance: export_sac_actor(model, cfg.env, provenance)  # noqa: E731
    else:
        env = VecNormalize(DummyVecEnv([lambda: wrap_env(make_gym_env(cfg.env))]), gamma=hyper["gamma"])
        if resume:
            env = VecNormalize.load(resume / "vecnormalize.pkl", env.venv)
            model = PPO.load(resume / "model.zip", env=env, device="cpu")
        else:
            model = PPO("MlpPolicy", env, seed=cfg.seed, device="cpu", verbose=0, **hyper)
        export = lambda provenance: export_ppo_actor(model, env, cfg.env, provenance)  # noqa: E731
    if resume and cfg.hidden:  # a loaded model keeps its own layers
        trained_hidden = export({}).meta.hidden
        if trained_hidden != [cfg.hidden] * 2:
            raise ValueError(f"{resume} holds a network with hidden layers {trained_hidden}, not hidden:={cfg.hidden}")
    started = time.time() - state.get("train_seconds", 0.0)
    best = {"mean_return": state.get("best_mean_return", -np.inf)}
    commands = state.get("commands", []) + [command]

    def save_checkpoint(step: int) -> None:
        folder = Path(cfg.checkpoint)
        folder.mkdir(parents=True, exist_ok=True)
        model.save(folder / "model.zip")
        if cfg.algo == "ppo":
            env.save(folder / "vecnormalize.pkl")
        elif cfg.keep_buffer:
            model.save_replay_buffer(folder / "replay_buffer.pkl")
        (folder / "state.json").write_text(json.dumps({
            "env": cfg.env, "algo": cfg.algo, "steps": step, "train_seconds": round(time.time() - started, 1),
            "best_mean_return": best["mean_return"], "commands": commands}, indent=1))

    def evaluate(step: int) -> None:
        record = {
            "algorithm": f"stable-baselines3 {cfg.algo.upper()}",
            "hyperparameters": hyper,
            **made_by,
            **({"resumed_from": commands[:-1]} if len(commands) > 1 else {}),
            "steps": step,
            "train_seconds": round(time.time() - started, 1),
            "seed": cfg.seed,
            "torch": torch.__version__,
            **(provenance or {}),
        }
        policy = export(record)
        engine = RolloutEngine(cfg.env, policy, policy, n_envs=cfg.eval_episodes)
        returns = engine.rollout(cfg.eval_episodes, seed=seeds.SELECTION).returns
        engine.close()
        mean, std = float(returns.mean()), float(returns.std())
        kept = mean > best["mean_return"]
        log(
            f"[{label} {cfg.env}] step {step:>8d}  {record['train_seconds']:8.0f}s  "
            f"eval return {mean:9.1f} ± {std:7.1f}{'  (best, saved)' if kept else ''}{status()}",
            flush=True,
        )
        if kept:
            record["selection"] = {"eval_episodes": cfg.eval_episodes, "eval_seed": seeds.SELECTION, "mean_return": mean}
            best.update(mean_return=mean)
            save_policy(policy, out)
        if cfg.checkpoint:
            save_checkpoint(step)

    class EvalCallback(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps % cfg.eval_every == 0:
                evaluate(self.num_timesteps)
            return True

        def _on_rollout_end(self) -> None:
            if on_rollout_end is not None:
                on_rollout_end()

    model.learn(cfg.steps - model.num_timesteps, callback=EvalCallback(), reset_num_timesteps=not resume)
    if cfg.steps % cfg.eval_every:
        evaluate(model.num_timesteps)
    env.close()
    note = shadowed_by_bundled("expert", cfg.env, out)
    if note:
        log(note, flush=True)
    log(json.dumps({"env": cfg.env, "out": str(out), "best_eval_return": best["mean_return"],
                    "train_seconds": round(time.time() - started, 1)}), flush=True)
    return out

