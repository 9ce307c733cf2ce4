"""Engine throughput: raw gymnasium ``env.step`` on one env vs the rollout engine on ``n_envs`` envs with
policy + expert + attack in the loop.

    python -m aril_ros.benchmarks.engine env:=HalfCheetah-v5 steps:=20000 n_envs:=32

Prints steps/s of (1) gymnasium's ``env.step`` (as ``gym.make`` builds it, every wrapper) on one env with
precomputed random actions, (2) the engine in ``clean`` mode and (3) in ``sensory`` and ``physical`` mode
with the random attack, each with the graph's default policy (the bundled DAgger learner, a 64x64 MLP; or
``policy:=``) acting and the bundled expert (256x256) labelling, like the graph and the bare chain, and each
engine figure as a ratio of the raw one. The four are measured in one process, in ``rounds`` interleaved
slices of ``steps / rounds`` steps each (set-up excluded), and each figure is its best slice: on a shared
machine the load then falls on all four alike, and a slice another process interrupted does not count.
The last line is the figures as JSON (what ``aril report`` reads).
"""
import json
import sys
import time
from dataclasses import dataclass
from itertools import islice

import numpy as np
import torch

from ..args import arg, module_config
from ..attacks import make_attack
from ..envs import layout_of, make_gym_env
from ..policy import resolve_policy
from ..registry import DEFAULT_ENV, MAX_EPS, MODES
from ..rollout import RolloutEngine


@dataclass
class BenchConfig:
    """Arguments of ``python -m aril_ros.benchmarks.engine``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    steps: int = arg(20_000, "environment steps per measurement", low=1, high=10**9)
    rounds: int = arg(4, "interleaved slices each measurement is split into; each figure is its best slice",
                      low=1, high=1000)
    n_envs: int = arg(32, "simulators the engine runs side by side", low=1, high=1024)
    physics_threads: int = arg(0, "threads stepping the engine's physics (0: one per core)", low=0, high=256)
    policy: str = arg("bundled", "the acting policy: bundled (the graph's default), another bundled name or a policy "
                                 "file; the bundled expert labels")
    eps: float = arg(0.05, "attack budget for the attacked modes", low=0.0, high=MAX_EPS)
    threads: int = arg(1, "torch threads", low=1, high=256)


def raw_steps(env_id: str):
    """gymnasium's ``env.step`` with precomputed random actions: a function running ``k`` more steps, and
    the env."""
    env = make_gym_env(env_id)
    env.reset(seed=0)
    actions = iter(np.random.default_rng(0).uniform(-1, 1, (10**6, env.action_space.shape[0])))

    def run(k: int) -> int:
        for a in islice(actions, k):
            _, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                env.reset(seed=0)
        return k

    return run, env


def engine_steps(cfg: BenchConfig, mode: str):
    """The engine in ``mode``: a function running at least ``k`` more env steps (whole engine steps), and
    the engine."""
    policy, expert = resolve_policy(cfg.policy, cfg.env), resolve_policy("expert", cfg.env)
    attack = make_attack("none" if mode == "clean" else "random", layout_of(cfg.env), cfg.eps)
    engine = RolloutEngine(cfg.env, policy, expert, attack, mode, n_envs=cfg.n_envs,
                           physics_threads=cfg.physics_threads or None)
    batches = engine.iter_steps(episodes=10**9, seed=0)

    def run(k: int) -> int:
        done = 0
        while done < k:
            done += len(next(batches).episodes)
        return done

    return run, engine


def main(argv):
    cfg = module_config(BenchConfig, "python -m aril_ros.benchmarks.engine", __doc__, argv)
    if cfg is None:
        return
    torch.set_num_threads(cfg.threads)
    runners = {"raw env.step": raw_steps(cfg.env), **{f"engine {mode}": engine_steps(cfg, mode) for mode in MODES}}
    best = dict.fromkeys(runners, 0.0)
    per_slice = max(cfg.steps // max(cfg.rounds, 1), 1)
    for _ in range(max(cfg.rounds, 1)):
        for name, (run, _) in runners.items():
            started = time.perf_counter()
            done = run(per_slice)
            best[name] = max(best[name], done / (time.perf_counter() - started))
    how = runners["engine clean"][1].sims.sims[0].batched
    for _, owner in runners.values():
        owner.close()
    raw = best["raw env.step"]
    print(f"{cfg.env}, {cfg.steps} steps each in {cfg.rounds} interleaved slices (best slice), engine "
          f"n_envs={cfg.n_envs}, policy {cfg.policy} + expert + attack, physics threads="
          f"{cfg.physics_threads or 'one per core'}, torch threads={cfg.threads}; {how}")
    print(f"{'':<18}{'steps/s':>10}{'vs raw':>9}")
    for name, value in best.items():
        print(f"{name:<18}{value:>10.0f}{value / raw:>9.2f}")
    print(json.dumps({"env": cfg.env, "n_envs": cfg.n_envs, **{k: round(v, 1) for k, v in best.items()},
                      **{f"{k} vs raw": round(v / raw, 3) for k, v in best.items() if k != "raw env.step"}}))


if __name__ == "__main__":
    main(sys.argv[1:])
