"""A surrogate: a copy of a black-box policy learned from its answers alone, for attacks to use in its place.

A policy that arrives as a ROS 2 node gives no weights and no gradients, and each of its answers costs a round trip.
The surrogate is asked instead: white-box FGSM^k on it transfers to the policy (attack ``transfer``), and ARIL-A
trains against it at the engine's speed (:mod:`aril_ros.verdict`). Made in four named steps:

1. **visit**: the policy drives ``episodes`` episodes of its env (every other one under uniform noise of ±eps in
   the attacked mode, so the states an attack leads to are visited too), from :data:`aril_ros.seeds.SURROGATE`;
2. **probe**: at every visited observation the policy is asked again at ``probes`` points of the ±eps box around it
   (random corners, and corners scaled by a random factor): where the attacks will look;
3. **fit**: an MLP (the policy-file architecture, tanh) regresses the answers, minibatch Adam, a fixed seed;
4. **judge**: its fidelity on a tenth of the answers held out: the mean ``||surrogate - policy||^2`` and the share
   of the answers' variance it explains (R^2), kept in the file's provenance and printed.

The file is a policy file (:mod:`aril_ros.policy`) whose provenance names ``algorithm: surrogate``, the victim, the
queries it took and its fidelity; it never holds the victim's parameters, only what the victim answered.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from . import seeds
from .args import arg
from .envs import HORIZON, layout_of
from .policy import MLPPolicy, meta_for_env, save_policy
from .provenance import stamp
from .rollout import SimBatch
from .step import episode_rng, episode_seed

ASK_ROWS = 256
"""Rows per question put to the victim: a ROS node answers a probe message of this many observations in one round
trip, not a whole data set in one message."""


@dataclass
class SurrogateConfig:
    """How a surrogate is made (the black-box pipeline's defaults)."""

    episodes: int = arg(10, "episodes the victim drives (every other one under uniform noise)", low=1, high=10_000)
    probes: int = arg(3, "extra questions per visited observation, at points of the ±eps box around it",
                      low=0, high=1000)
    hidden: int = arg(256, "width of the surrogate's two hidden layers", low=1, high=4096)
    epochs: int = arg(30, "passes over the answers", low=1, high=10_000)
    seed: int = arg(0, "seed of the probes, the weights and the minibatches", low=0, high=2**31 - 1)


def fit_surrogate(victim, env_id: str, mode: str, eps: float, out: str | Path, cfg: SurrogateConfig = SurrogateConfig(),
                  victim_name: str = "", log=print, horizon: int = HORIZON) -> Path:
    """The surrogate of ``victim`` (anything with ``act(obs_batch)``) in ``mode`` at ``eps``, from episodes of
    ``horizon`` steps, written to ``out``."""
    started = time.time()
    questions, answers = gather(victim, env_id, mode, eps, cfg, horizon, np.random.default_rng(cfg.seed))
    made = {"victim": victim_name, "mode": mode, "eps": eps, "horizon": horizon, "queries": int(len(questions))}
    return fit_answers(questions, answers, env_id, cfg, made, out, log, started)


def gather(victim, env_id: str, mode: str, eps: float, cfg: SurrogateConfig, horizon: int, rng: np.random.Generator,
           attack=None, first: int = seeds.SURROGATE) -> tuple[np.ndarray, np.ndarray]:
    """Steps 1 and 2: the questions put to ``victim`` and its answers: ``cfg.episodes`` episodes from env seed
    ``first`` (under ``attack``, or every other one under noise) and ``cfg.probes`` points around each step."""
    visited, driven = visit(victim, env_id, mode, eps, cfg.episodes, horizon, attack, first)
    probes = probe_points(visited, layout_of(env_id), eps, cfg.probes, rng)
    return np.concatenate([visited, probes]), np.concatenate([driven, ask(victim, probes)])


def fit_answers(questions: np.ndarray, answers: np.ndarray, env_id: str, cfg: SurrogateConfig, made: dict,
                out: str | Path, log=print, started: float | None = None) -> Path:
    """Steps 3 and 4: the surrogate fitted to ``answers`` and judged on a tenth held out, written to ``out`` with
    ``made`` (what it copies, and how) in its provenance."""
    started = time.time() if started is None else started
    rng = np.random.default_rng(cfg.seed)
    held_out = rng.permutation(len(questions))[: len(questions) // 10]
    train = np.setdiff1d(np.arange(len(questions)), held_out)
    torch.manual_seed(cfg.seed)  # the initial weights
    surrogate = MLPPolicy(meta_for_env(env_id, hidden=[cfg.hidden, cfg.hidden], activation="tanh", squash="tanh",
                                       obs_mean=questions.mean(0).tolist(),
                                       obs_std=(questions.std(0) + 1e-6).tolist()))
    fit(surrogate, questions[train], answers[train], cfg)
    fidelity = judge(surrogate, questions[held_out], answers[held_out])
    surrogate.meta.provenance = {**stamp("aril fit-surrogate", cfg), "algorithm": "surrogate", **made,
                                 "answers": int(len(questions)), "fidelity": fidelity,
                                 "seconds": round(time.time() - started, 1)}
    path = save_policy(surrogate, out)
    log(f"[surrogate] {path}: {made['queries']:,} questions to the victim, held-out error {fidelity['mse']:.4f} "
        f"(R^2 {fidelity['r2']:.4f}), {time.time() - started:.0f} s")
    return path


def visit(victim, env_id: str, mode: str, eps: float, episodes: int, horizon: int = HORIZON, attack=None,
          first: int = seeds.SURROGATE) -> tuple[np.ndarray, np.ndarray]:
    """What the victim saw, step by step, driving ``episodes`` episodes of ``horizon`` steps from env seed ``first``,
    and what it answered (its first questions: asked once, kept); under ``attack`` (an
    :class:`~aril_ros.attacks.Attack`), or the odd episodes under uniform ±eps noise (in ``mode``: seen, or written
    into the simulator's state)."""
    layout = layout_of(env_id)
    sims = SimBatch(env_id, episodes, horizon)
    rngs = [episode_rng(first, e) for e in range(episodes)]
    obs = sims.reset([episode_seed(first, e) for e in range(episodes)])
    running, seen_rows, answer_rows = np.arange(episodes), [], []
    try:
        while running.size:
            if attack is not None:
                delta = attack.perturb(obs[running], [rngs[e] for e in running])
            else:
                delta = np.zeros_like(obs[running])
                for row, e in enumerate(running):
                    if e % 2:
                        delta[row, : layout.n_position] = rngs[e].uniform(-eps, eps, layout.n_position)
            seen = sims.seen(mode, obs[running], delta, running)
            seen_rows.append(seen)
            answer_rows.append(victim.act(seen))
            obs[running], _, terminated, truncated = sims.step(answer_rows[-1], running)
            running = running[~(terminated | truncated)]
    finally:
        sims.close()
    return np.concatenate(seen_rows), np.concatenate(answer_rows)


def probe_points(obs: np.ndarray, layout, eps: float, probes: int, rng: np.random.Generator) -> np.ndarray:
    """``probes`` points around each observation: even ones a random corner of the ±eps box, odd ones a corner scaled
    by a random factor in [0, 1) (the attacks' candidates lie on and inside the box)."""
    points = []
    n_pos = layout.n_position
    for k in range(probes):
        delta = np.zeros_like(obs)
        delta[:, :n_pos] = eps * rng.choice([-1.0, 1.0], size=(len(obs), n_pos))
        if k % 2:
            delta[:, :n_pos] *= rng.random((len(obs), 1))
        points.append(obs + delta)
    return np.concatenate(points) if points else np.zeros((0, obs.shape[1]))


def ask(victim, questions: np.ndarray) -> np.ndarray:
    """The victim's answers to ``questions``, put :data:`ASK_ROWS` at a time."""
    return np.concatenate([victim.act(questions[i : i + ASK_ROWS]) for i in range(0, len(questions), ASK_ROWS)])


def fit(surrogate: MLPPolicy, questions: np.ndarray, answers: np.ndarray, cfg: SurrogateConfig) -> None:
    """Regress ``answers`` on ``questions``: squared error, Adam (lr 1e-3), minibatches of 256, ``cfg.epochs``."""
    x, y = torch.as_tensor(questions, dtype=torch.float32), torch.as_tensor(answers, dtype=torch.float32)
    gen = torch.Generator().manual_seed(cfg.seed)
    optimizer = torch.optim.Adam(surrogate.parameters(), lr=1e-3)
    surrogate.train()
    for _ in range(cfg.epochs):
        for batch in torch.randperm(len(x), generator=gen).split(256):
            loss = ((surrogate(x[batch]) - y[batch]) ** 2).sum(1).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    surrogate.eval()


def judge(surrogate: MLPPolicy, questions: np.ndarray, answers: np.ndarray) -> dict:
    """Fidelity on held-out answers: mean squared error per answer and R^2 (share of their variance explained)."""
    error = float(((surrogate.act(questions) - answers) ** 2).sum(1).mean())
    variance = float(((answers - answers.mean(0)) ** 2).sum(1).mean())
    return {"mse": round(error, 6), "r2": round(1.0 - error / variance, 6), "held_out": int(len(questions))}
