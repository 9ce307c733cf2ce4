"""Supervised learners: behaviour cloning, the LEARNER of DAgger and ARIL (paper Alg. 1, line 9).

:func:`fit_policy` regresses a fresh two-hidden-layer MLP onto a :class:`DaggerDataset` (mean squared
error on the expert's actions, Adam at the paper's lr 1e-3), with the observation normalisation
taken from the data and stored in the policy file. :func:`train_bc` is the floor of the defenses:
clean expert demonstrations, one fit.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from . import seeds
from .args import arg
from .dataset import DaggerDataset
from .policy import MLPPolicy, meta_for_env, resolve_policy, save_policy
from .provenance import stamp
from .registry import DEFAULT_ENV, shadowed_by_bundled, user_path
from .rollout import RolloutEngine


def fit_policy(data: DaggerDataset, env_id: str, hidden: int = 64, epochs: int = 30, lr: float = 1e-3,
               batch: int = 256, seed: int = 0, provenance: dict | None = None) -> MLPPolicy:
    """A new policy fitted to ``data`` (deterministic for a seed: its own generators, none global)."""
    meta = meta_for_env(env_id, hidden=[hidden, hidden], activation="relu", squash="tanh",
                        obs_mean=data.obs.mean(0).tolist(), obs_std=(data.obs.std(0) + 1e-6).tolist(),
                        obs_clip=10.0, provenance=provenance or {})
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        policy = MLPPolicy(meta)
    optimizer = torch.optim.Adam(policy.net.parameters(), lr=lr)
    x = torch.as_tensor(data.obs, dtype=torch.float32)
    y = torch.as_tensor(data.expert_action, dtype=torch.float32)
    gen = torch.Generator().manual_seed(seed)
    loss = torch.tensor(float("nan"))
    for _ in range(epochs):
        for idx in torch.randperm(len(x), generator=gen).split(batch):
            loss = ((policy(x[idx]) - y[idx]) ** 2).sum(-1).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    policy.meta.provenance = {**policy.meta.provenance, "final_train_loss": float(loss.detach())}
    return policy.eval()


@dataclass
class BCConfig:
    """Arguments of ``aril train-bc``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    expert: str = arg("expert", "the demonstrator: a bundled name or a policy file")
    episodes: int = arg(10, "clean expert demonstrations (1000 steps each)", low=1, high=100_000)
    hidden: int = arg(64, "width of the two hidden layers", low=1, high=4096)
    epochs: int = arg(30, "passes over the demonstrations", low=0, high=100_000)
    lr: float = arg(1e-3, "Adam learning rate (the paper's appendix)", low=0.0, high=1.0)
    batch: int = arg(256, "minibatch size", low=1, high=10**7)
    seed: int = arg(0, "seed of the weights and the batches; the demonstrations take the seed's training "
                       "block (aril_ros.seeds.collection(seed, 0))", low=0, high=2**31 - 1)
    out: str = arg("", "where to write the policy (default: bc/<env>.pt in the user data folder, $ARIL_DATA)")


def train_bc(cfg: BCConfig, log=print) -> Path:
    started = time.time()
    torch.set_num_threads(1)
    expert = resolve_policy(cfg.expert, cfg.env)
    engine = RolloutEngine(cfg.env, expert, expert, n_envs=min(cfg.episodes, 32))
    demos = DaggerDataset.from_trajectories(engine.rollout(cfg.episodes, seed=seeds.collection(cfg.seed, 0)))
    log(f"[train-bc {cfg.env}] {len(demos)} expert steps from {cfg.episodes} episodes", flush=True)
    provenance = {"algorithm": "behaviour cloning", **stamp("aril train-bc", cfg), "expert": cfg.expert,
                  "expert_provenance": expert.meta.provenance, "samples": len(demos), "seed": cfg.seed}
    policy = fit_policy(demos, cfg.env, cfg.hidden, cfg.epochs, cfg.lr, cfg.batch, cfg.seed, provenance)
    returns = RolloutEngine(cfg.env, policy, expert, n_envs=5).rollout(5, seed=seeds.SELECTION).returns
    policy.meta.provenance["eval"] = {"episodes": 5, "seed": seeds.SELECTION, "mean_return": float(returns.mean())}
    policy.meta.provenance["train_seconds"] = round(time.time() - started, 1)
    out = save_policy(policy, cfg.out or user_path("bc", cfg.env))
    note = shadowed_by_bundled("bc", cfg.env, out)
    if note:
        log(note)
    log(json.dumps({"env": cfg.env, "out": str(out), "eval_return": round(float(returns.mean()), 1)}))
    return out
