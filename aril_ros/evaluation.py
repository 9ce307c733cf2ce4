"""Evaluating a policy under a mode, an attack and a budget, on the in-process engine."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch

from .args import arg
from .attacks import ATTACK_NAMES, attack_budget, attack_for_mode, make_attack
from .envs import layout_of
from .experts import resolve_policy
from .rollout import MODES, RolloutEngine


@dataclass
class EvalConfig:
    """Arguments of ``aril eval``."""

    env: str = arg("HalfCheetah-v5", "gymnasium MuJoCo env id")
    policy: str = arg("expert", "policy to evaluate: a bundled name (expert, dagger, dart, gail, bc; dr and aril take "
                                "the one of mode:=) or a policy file path")
    expert: str = arg("expert", "expert that labels the true states: a bundled name or a file path")
    mode: str = arg("clean", f"one of {', '.join(MODES)}")
    attack: str = arg("", f"one of {', '.join(ATTACK_NAMES)} (default: none when clean, random otherwise)")
    eps: float = arg(0.0, "L-infinity bound of the perturbation on the zero-order entries (0: the calibrated one for "
                          "env and mode, results/eps_calibration.json; aril_a: its adversary's)")
    k: int = arg(10, "steps of fgsm_k")
    attack_file: str = arg("", "aril_a: the adversary file (from aril train-adversary)")
    rescale: bool = arg(False, "aril_a at an eps:= other than its own: scale its perturbation by eps / its eps")
    episodes: int = arg(5, "number of episodes (env seeds seed, seed+1, ...)")
    seed: int = arg(0, "seed of the first episode and of the attack noise")
    n_envs: int = arg(32, "simulators run side by side (does not change the results)")
    horizon: int = arg(1000, "steps per episode")
    threads: int = arg(1, "torch threads (more only slows these small networks down)")


def evaluate(cfg: EvalConfig, progress=None) -> dict:
    """Run ``cfg.episodes`` episodes; ``progress(episode, return, expert_loss, steps, max_delta)`` is
    called as each ends. Returns the summary (mean/std return, mean expert loss, per-episode returns)."""
    torch.set_num_threads(cfg.threads)
    attack_name = attack_for_mode(cfg.mode, cfg.attack)
    layout = layout_of(cfg.env)  # an unknown or non-MuJoCo id is the first thing to report
    policy = resolve_policy(cfg.policy, cfg.env, cfg.mode)
    expert = resolve_policy(cfg.expert, cfg.env)
    attack = make_attack(attack_name, layout, attack_budget(cfg.env, cfg.mode, attack_name, cfg.eps), victim=policy,
                         expert=expert, steps=cfg.k if attack_name == "fgsm_k" else None,
                         adversary=cfg.attack_file, mode=cfg.mode, rescale=cfg.rescale)
    engine = RolloutEngine(cfg.env, policy, expert, attack, cfg.mode, min(cfg.n_envs, cfg.episodes), cfg.horizon)
    started = time.time()
    returns = np.zeros(cfg.episodes)
    sq_loss = np.zeros(cfg.episodes)
    length = np.zeros(cfg.episodes, dtype=int)
    max_delta = np.zeros(cfg.episodes)
    steps = 0
    for step in engine.iter_steps(cfg.episodes, cfg.seed):
        e = step.episodes
        returns[e] += step.reward
        sq_loss[e] += ((step.action - step.expert_action) ** 2).sum(axis=1)
        length[e] += 1
        max_delta[e] = np.maximum(max_delta[e], np.abs(step.delta).max(axis=1))
        steps += len(e)
        for k in e[step.done] if progress else ():
            progress(int(k), returns[k], sq_loss[k] / length[k], int(length[k]), max_delta[k])
    engine.close()
    seconds = time.time() - started
    summary = {
        "env": cfg.env, "policy": cfg.policy, "expert": cfg.expert, "mode": cfg.mode, "attack": attack_name,
        "eps": engine.attack.eps, "episodes": cfg.episodes, "seed": cfg.seed,
        "mean_return": round(float(returns.mean()), 3), "std_return": round(float(returns.std()), 3),
        "mean_expert_loss": round(float(sq_loss.sum() / length.sum()), 6),
        "steps": int(steps), "steps_per_s": round(steps / seconds, 1),
        "returns": [round(float(r), 3) for r in returns],
    }
    return summary


