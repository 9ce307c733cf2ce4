"""A surrogate: a copy of a black-box policy learned from its answers alone, for attacks to use in its place.

A policy that arrives as a ROS 2 node gives no weights and no gradients, and each of its answers costs a round trip.
The surrogate is asked instead: white-box FGSM^k on it transfers to the policy (attack ``transfer``), and ARIL-A
trains against it at the engine's speed (:mod:`aril_ros.verdict`). Made in four named steps:

1. **visit**: the policy drives ``episodes`` episodes of its env (every other one under uniform noise of ±eps in
   the attacked mode, so the states an attack leads to are visited too), from :data:`aril_ros.seeds.SURROGATE`;
2. **probe**: at every visited observation the policy is asked again at ``probes`` points of the ±eps box around it
   (random corners, and corners scaled by a random factor): where the attacks will look;
3. **fit**: an MLP (the policy-file architecture, tanh) regresses the answers, and each probe's answer *minus the
   answer at its visited observation* (the policy's variation inside the box, which is what an attack on the copy
   follows: a copy fitted to the answers alone explained about two thirds of it on the bundled HalfCheetah ARIL
   learner, and its loss gradient agreed with the policy's in sign on 74% of the entries); minibatch Adam with the
   step size decayed to zero, a fixed seed;
4. **judge**: its fidelity on a tenth of the visited observations held out, with their probes: the mean
   ``||surrogate - policy||^2``, the share of the answers' variance it explains (R^2) and the share of the
   variation inside the box it explains (local R^2), kept in the file's provenance and printed.

Questions and answers are kept grouped: ``[visited observations, 1 + probes, dim]``, the visited observation first.

The file is a policy file (:mod:`aril_ros.policy`) whose provenance names ``algorithm: surrogate``, the victim, the
queries it took and its fidelity; it never holds the victim's parameters, only what the victim answered.
"""
from __future__ import annotations

import math
import time
from contextlib import contextmanager
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
                      low=1, high=1000)
    hidden: int = arg(256, "width of the surrogate's two hidden layers", low=1, high=4096)
    updates: int = arg(7_500, "Adam updates at most (the fit's time: 40-60 s on one core for 256 wide)",
                       low=1, high=10_000_000)
    epochs: int = arg(200, "passes over the answers at most (a small data set stops here, long before the updates)",
                      low=1, high=10_000)
    batch: int = arg(256, "visited observations per update, each with its probes", low=1, high=100_000)
    lr: float = arg(2e-3, "Adam's first step size, decayed to zero along a cosine over the updates", low=0.0, high=1.0)
    local: float = arg(4.0, "weight of the variation inside the box (probe minus visited answer) in the loss",
                       low=0.0, high=1e6)
    seed: int = arg(0, "seed of the probes, the weights and the minibatches", low=0, high=2**31 - 1)


def fit_surrogate(victim, env_id: str, mode: str, eps: float, out: str | Path, cfg: SurrogateConfig = SurrogateConfig(),
                  victim_name: str = "", log=print, horizon: int = HORIZON) -> Path:
    """The surrogate of ``victim`` (anything with ``act(obs_batch)``) in ``mode`` at ``eps``, from episodes of
    ``horizon`` steps, written to ``out``."""
    started = time.time()
    questions, answers = gather(victim, env_id, mode, eps, cfg, horizon)
    made = {"victim": victim_name, "mode": mode, "eps": eps, "horizon": horizon,
            "queries": int(questions[..., 0].size)}
    return fit_answers(questions, answers, env_id, cfg, made, out, log, started)


def gather(victim, env_id: str, mode: str, eps: float, cfg: SurrogateConfig, horizon: int
           ) -> tuple[np.ndarray, np.ndarray]:
    """Steps 1 and 2: the questions put to ``victim`` and its answers, grouped (``[visited, 1 + probes, dim]``):
    ``cfg.episodes`` episodes (every other one under noise) and ``cfg.probes`` points around each step, drawn from
    ``cfg.seed``."""
    visited, driven = visit(victim, env_id, mode, eps, cfg.episodes, horizon)
    probes = probe_points(visited, layout_of(env_id), eps, cfg.probes, np.random.default_rng(cfg.seed))
    answers = ask(victim, probes.reshape(-1, probes.shape[-1])).reshape(len(visited), cfg.probes, -1)
    return (np.concatenate([visited[:, None], probes], axis=1),
            np.concatenate([driven[:, None], answers], axis=1))


def fit_answers(questions: np.ndarray, answers: np.ndarray, env_id: str, cfg: SurrogateConfig, made: dict,
                out: str | Path, log=print, started: float | None = None) -> Path:
    """Steps 3 and 4: the surrogate fitted to the grouped ``answers`` and judged on a tenth of the visited
    observations held out (with their probes), written to ``out`` with ``made`` (what it copies, and how) in its
    provenance, and reported in ``log`` (None: not at all)."""
    started = time.time() if started is None else started
    rng = np.random.default_rng(cfg.seed)
    held_out = rng.permutation(len(questions))[: len(questions) // 10]
    train = np.setdiff1d(np.arange(len(questions)), held_out)
    rows = questions.reshape(-1, questions.shape[-1])
    torch.manual_seed(cfg.seed)  # the initial weights
    surrogate = MLPPolicy(meta_for_env(env_id, hidden=[cfg.hidden, cfg.hidden], activation="tanh", squash="tanh",
                                       obs_mean=rows.mean(0).tolist(), obs_std=(rows.std(0) + 1e-6).tolist()))
    fit(surrogate, questions[train], answers[train], cfg)
    with one_thread():  # the figures in its provenance, too, the same wherever it was fitted
        fidelity = judge(surrogate, questions[held_out], answers[held_out])
    surrogate.meta.provenance = {**stamp("aril fit-surrogate", cfg), "algorithm": "surrogate", **made,
                                 "answers": int(len(rows)), "fidelity": fidelity,
                                 "seconds": round(time.time() - started, 1)}
    path = save_policy(surrogate, out)
    if log:
        log(summary(path, surrogate.meta.provenance))
    return path


def summary(path: Path, made: dict) -> str:
    """The line that reports a surrogate at ``path`` made as its provenance ``made`` says."""
    fidelity = made["fidelity"]
    return (f"[surrogate] {path}: {made['queries']:,} questions to the victim, held-out error {fidelity['mse']:.4f} "
            f"(R^2 {fidelity['r2']:.4f}, inside the box {fidelity['local_r2']:.4f}), {made['seconds']:.0f} s")


@contextmanager
def one_thread():
    """Torch on one thread inside, whatever the caller set: a fit's bits depend on the thread count, and the copy
    must be the same file whoever asks and wherever it runs (a file and the node serving it get one verdict; a
    sweep task's worker has its own count). Two fits run side by side instead (:func:`aril_ros.verdict.run_pipelines`)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def visit(victim, env_id: str, mode: str, eps: float, episodes: int, horizon: int = HORIZON
          ) -> tuple[np.ndarray, np.ndarray]:
    """What the victim saw, step by step, driving ``episodes`` episodes of ``horizon`` steps from env seed
    :data:`aril_ros.seeds.SURROGATE`, and what it answered (its first questions: asked once, kept); the odd episodes
    under uniform ±eps noise (in ``mode``: seen, or written into the simulator's state)."""
    first = seeds.SURROGATE
    layout = layout_of(env_id)
    sims = SimBatch(env_id, episodes, horizon)
    rngs = [episode_rng(first, e) for e in range(episodes)]
    obs = sims.reset([episode_seed(first, e) for e in range(episodes)])
    running, seen_rows, answer_rows = np.arange(episodes), [], []
    try:
        while running.size:
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
    """``probes`` points around each observation (``[len(obs), probes, dim]``): even ones a random corner of the ±eps
    box, odd ones a corner scaled by a random factor in [0, 1) (the attacks' candidates lie on and inside the box)."""
    points = []
    n_pos = layout.n_position
    for k in range(probes):
        delta = np.zeros_like(obs)
        delta[:, :n_pos] = eps * rng.choice([-1.0, 1.0], size=(len(obs), n_pos))
        if k % 2:
            delta[:, :n_pos] *= rng.random((len(obs), 1))
        points.append(obs + delta)
    return np.stack(points, axis=1)


def ask(victim, questions: np.ndarray) -> np.ndarray:
    """The victim's answers to ``questions``, put :data:`ASK_ROWS` at a time."""
    return np.concatenate([victim.act(questions[i : i + ASK_ROWS]) for i in range(0, len(questions), ASK_ROWS)])


def fit(surrogate: MLPPolicy, questions: np.ndarray, answers: np.ndarray, cfg: SurrogateConfig) -> None:
    """Regress the grouped ``answers`` on ``questions``: the squared error of each answer plus ``cfg.local`` times
    that of each probe's variation from its visited observation's answer; Adam from ``cfg.lr`` decayed to zero along
    a cosine, ``cfg.batch`` visited observations (with their probes) an update, ``cfg.updates`` updates or
    ``cfg.epochs`` passes, whichever is fewer; on :func:`one_thread`."""
    x, y = torch.as_tensor(questions, dtype=torch.float32), torch.as_tensor(answers, dtype=torch.float32)
    updates = min(cfg.updates, cfg.epochs * -(-len(x) // cfg.batch))
    gen = torch.Generator().manual_seed(cfg.seed)
    optimizer = torch.optim.Adam(surrogate.parameters(), lr=cfg.lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda done: 0.5 * (1 + math.cos(math.pi * done / updates)))
    surrogate.train()
    try:
        with one_thread():
            done = 0
            while done < updates:
                for group in torch.randperm(len(x), generator=gen).split(cfg.batch)[: updates - done]:
                    out = surrogate(x[group].reshape(-1, x.shape[-1])).reshape(y[group].shape)
                    error = ((out - y[group]) ** 2).sum(-1).mean()
                    variation = (((out[:, 1:] - out[:, :1]) - (y[group, 1:] - y[group, :1])) ** 2).sum(-1).mean()
                    optimizer.zero_grad()
                    (error + cfg.local * variation).backward()
                    optimizer.step()
                    schedule.step()
                    done += 1
    finally:
        surrogate.eval()


def judge(surrogate: MLPPolicy, questions: np.ndarray, answers: np.ndarray) -> dict:
    """Fidelity on held-out grouped answers: mean squared error per answer, R^2 (share of their variance explained)
    and local R^2 (share of the variance of each probe's answer minus its visited observation's explained: what
    an attack on the copy follows)."""
    guess = surrogate.act(questions.reshape(-1, questions.shape[-1])).reshape(answers.shape)
    rows, guessed = answers.reshape(-1, answers.shape[-1]), guess.reshape(-1, answers.shape[-1])
    error = float(((guessed - rows) ** 2).sum(1).mean())
    variance = float(((rows - rows.mean(0)) ** 2).sum(1).mean())
    moved, guessed_moved = answers[:, 1:] - answers[:, :1], guess[:, 1:] - guess[:, :1]
    local_error = float(((guessed_moved - moved) ** 2).sum(-1).mean())
    local_variance = float(((moved - moved.reshape(-1, moved.shape[-1]).mean(0)) ** 2).sum(-1).mean())
    return {"mse": round(error, 6), "r2": round(1.0 - error / variance, 6),
            "local_r2": round(1.0 - local_error / local_variance, 6), "held_out": int(len(rows))}
