"""Engine overhead benchmark: raw ``env.step`` vs the rollout engine with policy + expert in the loop.

    python -m aril_ros.benchmarks.engine env:=HalfCheetah-v5 steps:=20000 n_envs:=8

Prints steps/s of (1) gymnasium ``env.step`` with precomputed random actions, (2) the engine in
``clean`` mode and (3) in ``sensory`` and ``physical`` mode with the random attack, each with the
bundled expert (or ``policy:=``) as both policy and labeller, and each engine figure as a ratio of the raw
one; the last line is the figures as JSON (what ``aril report`` reads).
"""
import json
import sys
import time
from dataclasses import dataclass

import numpy as np
import torch

from ..args import arg, parse_args, usage
from ..attacks import make_attack
from ..envs import layout_of, make_gym_env
from ..policy import resolve_policy
from ..registry import DEFAULT_ENV, MODES
from ..rollout import RolloutEngine


@dataclass
class BenchConfig:
    """Arguments of ``python -m aril_ros.benchmarks.engine``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    steps: int = arg(20_000, "environment steps per measurement")
    n_envs: int = arg(32, "simulators the engine runs side by side")
    policy: str = arg("expert", "policy (and labeller): a bundled name or a policy file")
    eps: float = arg(0.05, "attack budget for the attacked modes")
    threads: int = arg(1, "torch threads")


def raw_steps_per_s(env_id: str, steps: int) -> float:
    """gymnasium's ``env.step`` (as ``gym.make`` builds it) with precomputed random actions."""
    env = make_gym_env(env_id)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, env.action_space.shape[0]))
    started = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            env.reset(seed=0)
    return steps / (time.perf_counter() - started)


def engine_steps_per_s(cfg: BenchConfig, mode: str) -> float:
    expert = resolve_policy(cfg.policy, cfg.env)
    attack = make_attack("none" if mode == "clean" else "random", layout_of(cfg.env), cfg.eps)
    engine = RolloutEngine(cfg.env, expert, expert, attack, mode, n_envs=cfg.n_envs)
    started, done = time.perf_counter(), 0
    for step in engine.iter_steps(episodes=10**6, seed=0):
        done += len(step.episodes)
        if done >= cfg.steps:
            break
    seconds = time.perf_counter() - started
    engine.close()
    return done / seconds


def main(argv):
    if "--help" in argv or "-h" in argv:
        print(usage(BenchConfig, "python -m aril_ros.benchmarks.engine", __doc__.strip().splitlines()[0]))
        return
    cfg = parse_args(BenchConfig, argv)
    torch.set_num_threads(cfg.threads)
    raw = raw_steps_per_s(cfg.env, cfg.steps)
    rows = {"raw env.step": raw}
    for mode in MODES:
        rows[f"engine {mode}"] = engine_steps_per_s(cfg, mode)
    print(f"{cfg.env}, {cfg.steps} steps each, engine n_envs={cfg.n_envs}, torch threads={cfg.threads}")
    print(f"{'':<18}{'steps/s':>10}{'vs raw':>9}")
    for name, value in rows.items():
        print(f"{name:<18}{value:>10.0f}{value / raw:>9.2f}")
    print(json.dumps({"env": cfg.env, "n_envs": cfg.n_envs, **{k: round(v, 1) for k, v in rows.items()}}))


if __name__ == "__main__":
    main(sys.argv[1:])
