"""Adversary-training throughput: ARIL-A (ours) vs stable-baselines3 PPO on the same env.

    python -m aril_ros.benchmarks.adversary env:=HalfCheetah-v5 steps:=65536

Both train a two-hidden-layer (64) policy with a value head, 10 epochs per update, for the same
number of env steps, one torch thread each: ours the default adversary (categorical over {-eps, 0,
+eps} per zero-order entry, given the state and the victim's and the expert's actions on it), SB3's
PPO a Gaussian policy on the env reward — the tool a user would otherwise pick. Ours also runs the
victim twice (on the true and the perturbed state) and the expert at every step (the adversary's
inputs, reward and exact critic part). SB3 is measured with 1 env (its default) and with as many envs as ours.
With ``repeats`` above 1 the measurements take turns that many times and each figure is its best run: on a shared
machine a load that comes and goes then falls on both alike. The last line is the figures as JSON (what
``aril report`` reads).
"""
import json
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from ..adversary import AdversaryConfig, train_adversary
from ..args import arg, module_config
from ..envs import make_gym_env
from ..registry import DEFAULT_ENV, MAX_EPS


@dataclass
class AdversaryBenchConfig:
    """Arguments of ``python -m aril_ros.benchmarks.adversary``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    steps: int = arg(65_536, "env steps per measurement", low=1, high=10**9)
    n_envs: int = arg(64, "our simulators side by side (and SB3's vectorised measurement); 4096 steps per update",
                      low=1, high=1024)
    eps: float = arg(0.05, "the adversary's budget", low=0.0, high=MAX_EPS)
    repeats: int = arg(1, "turns of the three measurements; each figure is its best turn", low=1, high=100)


def ours(cfg) -> float:
    """Steps/s as the trainer measures it: from the first collected step, set-up excluded like SB3's."""
    lines = []
    with tempfile.TemporaryDirectory() as scratch:
        train_adversary(AdversaryConfig(env=cfg.env, eps=cfg.eps, steps=cfg.steps, n_envs=cfg.n_envs,
                                        rollout=4096 // cfg.n_envs, minibatch=1024,
                                        out=str(Path(scratch) / "adversary.pt")),
                        log=lambda line, **_: lines.append(line))
    return json.loads(lines[-1])["steps_per_s"]


def sb3(cfg, n_envs: int) -> float:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv

    env = DummyVecEnv([lambda: make_gym_env(cfg.env)] * n_envs)
    model = PPO("MlpPolicy", env, n_steps=4096 // n_envs, batch_size=1024 if n_envs > 1 else 64,
                n_epochs=10, policy_kwargs={"net_arch": [64, 64]}, device="cpu", seed=0)
    started = time.perf_counter()
    model.learn(cfg.steps)
    return cfg.steps / (time.perf_counter() - started)


def main(argv):
    cfg = module_config(AdversaryBenchConfig, "python -m aril_ros.benchmarks.adversary", __doc__, argv)
    if cfg is None:
        return
    torch.set_num_threads(1)
    measurements = {f"ARIL-A (ours, {cfg.n_envs} envs)": lambda: ours(cfg), "SB3 PPO (1 env)": lambda: sb3(cfg, 1),
                    f"SB3 PPO ({cfg.n_envs} envs)": lambda: sb3(cfg, cfg.n_envs)}
    rows = dict.fromkeys(measurements, 0.0)
    for _ in range(cfg.repeats):
        for name, measure in measurements.items():
            rows[name] = max(rows[name], measure())
    base = rows["SB3 PPO (1 env)"]
    print(f"{cfg.env}: training env steps/s over {cfg.steps} steps, 1 torch thread, best of {cfg.repeats}")
    for name, value in rows.items():
        print(f"{name:<28}{value:>9.0f}{value / base:>8.2f}x")
    print(json.dumps({"env": cfg.env, "steps": cfg.steps, "repeats": cfg.repeats,
                      **{k: round(v, 1) for k, v in rows.items()}}))


if __name__ == "__main__":
    main(sys.argv[1:])
