"""Evaluating a policy under a mode, an attack and a budget, on the in-process engine."""
from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass

import torch

from . import seeds
from .args import arg
from .attacks import QueryAttack, make_attack
from .envs import HORIZON, layout_of
from .policy import resolve_policy
from .registry import ATTACKS, DEFAULT_ENV, MAX_EPS, MODES, attack_budget, choose_attack, for_task
from .rollout import RolloutEngine
from .step import EpisodeStats, summarise_episodes
from .timing import TimingAttack, timing_arg
from .sweep import run_tasks, shipped


@dataclass
class EvalConfig:
    """Arguments of ``aril eval``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    policy: str = arg("expert", "policy to evaluate: a bundled name (expert, dagger, dart, gail, bc; dr and aril take "
                                "the one of mode:=) or a policy file path")
    expert: str = arg("expert", "expert that labels the true states: a bundled name or a file path")
    mode: str = arg("clean", f"one of {', '.join(MODES)}")
    attack: str = arg("", f"one of {', '.join(ATTACKS)} (default: none when clean; attacked, the strongest bundled "
                          "for the policy: the ARIL-A trained against it, random where none is bundled)")
    eps: float = arg(0.0, "L-infinity bound of the perturbation on the zero-order entries (0: the calibrated one for "
                          "env and mode, bundled with aril_ros (aril calibrate-eps); aril_a: its adversary's)",
                     low=0.0, high=MAX_EPS)
    k: int = arg(0, "iterations of fgsm_k (0: 10), of spsa (0: 5) and of fd_fgsm (0: 1)", low=0, high=1000)
    samples: int = arg(0, "spsa: random directions per iteration, each queried at +- (0: 8)", low=0, high=1000)
    search: int = arg(0, "aril_a: query-time search over this many candidates drawn from the adversary (plus the one "
                         "it ranks highest), the victim queried on all, the most damaging applied (0: no search)",
                      low=0, high=1000)
    attack_file: str = arg("", "aril_a: the adversary file (from aril train-adversary); transfer: the surrogate file "
                                "(aril fit-surrogate)")
    rescale: bool = arg(False, "aril_a at an eps:= other than its own: scale its perturbation by eps / its eps")
    episodes: int = arg(5, "number of episodes (env seeds seed, seed+1, ...)", low=1, high=100_000)
    seed: int = arg(seeds.USER, "seed of the first episode and of the attack noise", low=0, high=2**31 - 1)
    n_envs: int = arg(32, "simulators run side by side (does not change the results)", low=1, high=1024)
    horizon: int = arg(HORIZON, "steps per episode", low=1, high=1_000_000)
    threads: int = arg(1, "torch threads (more only slows these small networks down)", low=1, high=256)
    delay: int = timing_arg("delay")
    drop: float = timing_arg("drop")
    action_delay: int = timing_arg("action_delay")
    timing: str = timing_arg("timing")
    timing_file: str = timing_arg("timing_file")


def evaluate(cfg: EvalConfig, progress=None) -> dict:
    """Run ``cfg.episodes`` episodes; ``progress(stats)`` is called with each episode's
    :class:`aril_ros.step.EpisodeStats` as it ends. Returns the summary (mean/std return, mean expert
    loss, per-episode returns; for a query attack its questions to the policy, ``queries``, and per step)."""
    torch.set_num_threads(cfg.threads)
    choice = choose_attack(cfg.env, cfg.mode, cfg.policy, cfg.attack, cfg.attack_file)
    attack_name = choice.name
    layout = layout_of(cfg.env)  # an unknown or non-MuJoCo id is the first thing to report
    policy = resolve_policy(cfg.policy, cfg.env, cfg.mode)
    expert = resolve_policy(cfg.expert, cfg.env)
    attack = make_attack(attack_name, layout, attack_budget(cfg.env, cfg.mode, attack_name, cfg.eps), victim=policy,
                         expert=expert, steps=cfg.k or None, samples=cfg.samples or None,
                         adversary=choice.file, mode=cfg.mode, rescale=cfg.rescale, search=cfg.search)
    timing = TimingAttack.of(cfg)
    engine = RolloutEngine(cfg.env, policy, expert, attack, cfg.mode, min(cfg.n_envs, cfg.episodes), cfg.horizon,
                           timing=timing)
    started = time.time()
    episodes = [EpisodeStats(e) for e in range(cfg.episodes)]
    for step in engine.iter_steps(cfg.episodes, cfg.seed):
        for row, e in enumerate(step.episodes):
            # the action acting at this step's state is the applied one (late under an action delay)
            episodes[e].add(step.reward[row], step.applied_action[row], step.expert_action[row], step.delta[row],
                            step.done[row])
            if step.done[row] and progress:
                progress(episodes[e])
    engine.close()
    summary = summarise_episodes(episodes)
    return {"env": cfg.env, "policy": cfg.policy, "expert": cfg.expert, "mode": cfg.mode, "attack": attack_name,
            "eps": engine.attack.eps, "seed": cfg.seed, **summary,
            **({"timing": timing.record()} if timing.budget.any else {}),
            **({"queries": attack.queries, "queries_per_step": round(attack.queries_per_step, 2)}
               if isinstance(attack, QueryAttack) else {}),
            "steps_per_s": round(summary["steps"] / (time.time() - started), 1)}


def evaluation_task(job: dict) -> dict:
    """:func:`evaluate` of ``EvalConfig(**job)``: one task of a sweep (:mod:`aril_ros.sweep`)."""
    return evaluate(EvalConfig(**job))


FILE_FIELDS = ("policy", "expert", "attack_file", "timing_file")
"""The EvalConfig fields that may name a file."""


def shipped_job(job: dict) -> dict:
    """``job`` (EvalConfig's fields, or any job naming its env, mode and these files: a graph run's) with the files it
    names marked to travel with its task: a cluster's nodes share no filesystem (nor the user's data: a name of an
    onboarded env's policy travels as its file)."""
    names = {"policy": for_task(job["policy"], job["env"], job.get("mode")),
             "expert": for_task(job.get("expert", "expert"), job["env"])}
    return {k: shipped(names.get(k, v)) if k in FILE_FIELDS else v for k, v in job.items()}


def evaluate_each(jobs: list[dict], workers: int, address: str, log, label: str = "evaluations"
                  ) -> Iterator[tuple[int, dict]]:
    """Each job's :func:`evaluate` result as ``(index, result)`` as it finishes, run as sweep tasks (``workers`` CPUs
    of a local Ray, or the cluster at ``address``; one worker: in this process, in order)."""
    return run_tasks(evaluation_task, [(shipped_job(job),) for job in jobs], workers, address, label=label, log=log)


def evaluate_all(jobs: list[dict], workers: int, address: str, log, label: str = "evaluations") -> list[dict]:
    """Each job's :func:`evaluate` result, in order (:func:`evaluate_each`)."""
    results: list[dict] = [{}] * len(jobs)
    for index, result in evaluate_each(jobs, workers, address, log, label):
        results[index] = result
    return results
