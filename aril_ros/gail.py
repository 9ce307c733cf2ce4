"""GAIL (Ho & Ermon, 2016), a defense baseline: imitation without the expert's labels on new states.

A discriminator ``D(s, a)`` learns to tell the expert's state-action pairs (``demos`` clean
demonstrations) from the generator's; the generator, stable-baselines3 PPO with the zoo's MuJoCo
settings (the loop of ``aril train-expert algo:=ppo``), maximises ``-log(1 - D(s, a))`` in place of
the environment's reward. After every PPO rollout the discriminator takes ``disc_epochs`` passes
over that rollout's pairs against as many expert pairs. The generator is kept by its evaluation
return, like the experts.

Why not the ``imitation`` library's GAIL: ``imitation`` 1.0.1 pins gymnasium~=0.29 and
stable-baselines3~=2.2 (no v5 MuJoCo envs), so it does not install beside our pins.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from . import seeds
from .args import arg
from .experts import ExpertConfig, train_expert
from .policy import resolve_policy
from .provenance import stamp
from .registry import DEFAULT_ENV
from .rollout import RolloutEngine


@dataclass
class GailConfig:
    """Arguments of ``aril train-gail``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    expert: str = arg("expert", "the demonstrator: a bundled name or a policy file")
    demos: int = arg(10, f"clean expert demonstrations (1000 steps each, env seeds {seeds.GAIL_DEMOS}...)",
                     low=1, high=100_000)
    steps: int = arg(1_000_000, "generator (PPO) environment steps", low=0, high=10**9)
    hidden: int = arg(64, "width of the generator's (the learner's) two hidden layers, and its critic's",
                      low=1, high=4096)
    disc_hidden: int = arg(64, "width of the discriminator's two hidden layers", low=1, high=4096)
    disc_lr: float = arg(3e-4, "discriminator Adam learning rate", low=0.0, high=1.0)
    disc_epochs: int = arg(2, "discriminator passes over each rollout", low=0, high=100_000)
    disc_batch: int = arg(256, "discriminator minibatch size", low=1, high=10**7)
    seed: int = arg(0, "seed of PPO, its env and the discriminator", low=0, high=2**31 - 1)
    eval_every: int = arg(50_000, "evaluate (and keep if best) the generator every this many steps", low=1, high=10**9)
    eval_episodes: int = arg(5, f"deterministic episodes per evaluation (env seeds {seeds.SELECTION}...)",
                             low=1, high=100_000)
    out: str = arg("", "where to write the policy (default runs/gail-<env>.pt)")
    threads: int = arg(1, "torch threads", low=1, high=256)


class Discriminator(nn.Module):
    """Logit of "this (s, a) pair is the expert's", on inputs normalised by the demonstrations."""

    def __init__(self, demo_obs: np.ndarray, demo_act: np.ndarray, hidden: int):
        super().__init__()
        pairs = np.concatenate([demo_obs, demo_act], axis=1)
        self.register_buffer("mean", torch.as_tensor(pairs.mean(0), dtype=torch.float32))
        std = pairs.std(0)
        # entries the demonstrations never move (Ant's contact forces on bodies that never touch) keep
        # unit scale: dividing by ~0 would turn any contact of the generator's there into a saturated input
        std = np.where(std > 1e-6, std + 1e-3, 1.0)
        self.register_buffer("std", torch.as_tensor(std, dtype=torch.float32))
        self.net = nn.Sequential(nn.Linear(pairs.shape[1], hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh(),
                                 nn.Linear(hidden, 1))

    def forward(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        x = ((torch.cat([obs, act], dim=-1) - self.mean) / self.std).clamp(-10.0, 10.0)
        return self.net(x).squeeze(-1)

    @torch.no_grad()
    def reward(self, obs: np.ndarray, act: np.ndarray) -> float:
        """``-log(1 - D(s, a))`` = softplus(logit): large where the pair looks like the expert's."""
        logit = self(torch.as_tensor(obs[None], dtype=torch.float32), torch.as_tensor(act[None], dtype=torch.float32))
        return float(nn.functional.softplus(logit)[0])


class DiscriminatorReward(gym.Wrapper):
    """Replaces the env's reward by the discriminator's and keeps the generator's (s, a) pairs."""

    def __init__(self, env: gym.Env, disc: Discriminator):
        super().__init__(env)
        self.disc, self.pairs, self._obs = disc, [], None

    def reset(self, **kwargs):
        self._obs, info = self.env.reset(**kwargs)
        return self._obs, info

    def step(self, action):
        obs, env_reward, terminated, truncated, info = self.env.step(action)
        action = np.asarray(action, dtype=np.float64)
        self.pairs.append((self._obs, action))
        reward = self.disc.reward(self._obs, action)
        self._obs = obs
        return obs, reward, terminated, truncated, {**info, "env_reward": env_reward}


def train_gail(cfg: GailConfig, log=print) -> Path:
    torch.set_num_threads(cfg.threads)
    expert = resolve_policy(cfg.expert, cfg.env)
    engine = RolloutEngine(cfg.env, expert, expert, n_envs=min(cfg.demos, 16))
    demos = engine.rollout(cfg.demos, seed=seeds.GAIL_DEMOS)
    engine.close()
    demo_obs, demo_act = demos.true_obs[demos.step_mask], demos.action[demos.step_mask]
    with torch.random.fork_rng():
        torch.manual_seed(cfg.seed)
        disc = Discriminator(demo_obs, demo_act, cfg.disc_hidden)
    optimizer = torch.optim.Adam(disc.parameters(), lr=cfg.disc_lr)
    gen = torch.Generator().manual_seed(cfg.seed)
    expert_obs = torch.as_tensor(demo_obs, dtype=torch.float32)
    expert_act = torch.as_tensor(demo_act, dtype=torch.float32)
    wrappers: list[DiscriminatorReward] = []
    stats = {"disc_loss": float("nan")}

    def wrap(env: gym.Env) -> gym.Env:
        wrappers.append(DiscriminatorReward(env, disc))
        return wrappers[-1]

    def train_discriminator() -> None:
        pairs = [pair for w in wrappers for pair in w.pairs]
        for w in wrappers:
            w.pairs.clear()
        obs = torch.as_tensor(np.stack([o for o, _ in pairs]), dtype=torch.float32)
        act = torch.as_tensor(np.stack([a for _, a in pairs]), dtype=torch.float32)
        for _ in range(cfg.disc_epochs):
            for idx in torch.randperm(len(obs), generator=gen).split(cfg.disc_batch):
                pick = torch.randint(len(expert_obs), (len(idx),), generator=gen)
                logits = torch.cat([disc(expert_obs[pick], expert_act[pick]), disc(obs[idx], act[idx])])
                labels = torch.cat([torch.ones(len(idx)), torch.zeros(len(idx))])
                loss = nn.functional.binary_cross_entropy_with_logits(logits, labels)
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
        stats["disc_loss"] = float(loss.detach())

    provenance = {"algorithm": "GAIL (generator: stable-baselines3 PPO)", "expert": cfg.expert,
                  "expert_provenance": expert.meta.provenance, "demos": cfg.demos,
                  "discriminator": {"hidden": cfg.disc_hidden, "lr": cfg.disc_lr, "epochs": cfg.disc_epochs}}
    generator = ExpertConfig(env=cfg.env, algo="ppo", steps=cfg.steps, seed=cfg.seed, hidden=cfg.hidden,
                             eval_every=cfg.eval_every,
                             eval_episodes=cfg.eval_episodes, out=cfg.out or f"runs/gail-{cfg.env}.pt",
                             threads=cfg.threads)
    return train_expert(generator, log=log, wrap_env=wrap, on_rollout_end=train_discriminator, label="train-gail",
                        made_by=stamp("aril train-gail", cfg), provenance=provenance, status=lambda: f"  disc loss {stats['disc_loss']:.3f}")
