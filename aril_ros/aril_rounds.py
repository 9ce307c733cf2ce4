"""ARIL's round adversaries (the paper's Algorithm 1): round ``r`` collects under f_r, an attack made
against the round's learner pi_r. f_r is a PPO adversary trained against pi_r (warm-started from f_{r-1}
with ``warm_start``); with ``adversary_seeds:=N`` the strongest of N such trainings by their own objective;
with ``round_attacks:=`` the strongest on pi_r of those trainings and the named query attacks, judged by
the paper's objective on the same episodes. The settings are :class:`~aril_ros.learner_config.RoundAdversaryConfig`.
"""
from __future__ import annotations

import dataclasses
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import seeds
from .adversary import AdversaryConfig, ready_adversaries
from .adversary_net import load_adversary
from .args import comma_list
from .attacks import make_attack
from .learner_config import LearnerConfig
from .learner_run import LearnerRun
from .step import disagreement
from .timing_adversary import load_timing_adversary


@dataclass
class RoundAdversary:
    """A round's f_t as the round collects under it."""

    attack: str
    """the attack's name (``aril_a`` for a trained adversary)"""
    file: str = ""
    """the adversary file, for ``aril_a``"""
    cpu_seconds: float = 0.0
    """the training time of every candidate it was chosen from (the round's compute, not its wall time)"""
    timing_file: str = ""
    """under a timing budget, ARIL's timing adversary trained against pi_t (its f_t in time)"""


def train_round_adversary(cfg: LearnerConfig, run: LearnerRun, r: int, log) -> RoundAdversary:
    """Round ``r``'s attack and adversary file: for ARIL, f_r trained against pi_r (warm-started from f_{r-1} if
    asked); with ``adversary_seeds`` > 1 the candidate whose objective (the mean episode loss of its last updates;
    0 when no episode finished) is largest, copied from ``adversary-<r>-seed<k>.pt``; with ``round_attacks`` the
    strongest on pi_r of the candidates and those attacks (:func:`strongest_on`). Else the run's attack, no file.
    Under a timing budget ARIL's f_r is timed too: a timing adversary trained against pi_r the same way (beside a
    value adversary, each trained against pi_r alone: the two together play the joint budget)."""
    if r == 0:
        return RoundAdversary(run.attack)
    made = value_round_adversary(cfg, run, r, log) if run.attack == "aril_a" else RoundAdversary(run.attack)
    if cfg.algorithm == "aril" and run.timing.any:
        timing_file, seconds = trained_candidate(cfg, run, r, "timing-adversary", log)
        made = dataclasses.replace(made, timing_file=str(timing_file), cpu_seconds=made.cpu_seconds + seconds)
    return made


def value_round_adversary(cfg: LearnerConfig, run: LearnerRun, r: int, log) -> RoundAdversary:
    """ARIL's f_r in value: the strongest trained candidate, or with ``round_attacks`` the strongest on pi_r of the
    candidates and those attacks."""
    if not cfg.round_attacks:
        file, seconds = trained_candidate(cfg, run, r, "adversary", log)
        return RoundAdversary("aril_a", str(file), seconds)
    candidates = round_candidates(cfg, run, r, "adversary")
    seconds = train_candidates(cfg, run, r, "adversary", candidates, log)
    attack, file = strongest_on(cfg, run, r, [("aril_a", str(f)) for f in candidates]
                                + [(name, "") for name in comma_list(cfg.round_attacks)], log)
    if file:
        shutil.copyfile(file, run.dir / f"adversary-{r}.pt")
        file = str(run.dir / f"adversary-{r}.pt")
    return RoundAdversary(attack, file, seconds)


def trained_candidate(cfg: LearnerConfig, run: LearnerRun, r: int, kind: str, log) -> tuple[Path, float]:
    """The ``kind`` (``adversary`` or ``timing-adversary``) file of round ``r``, ``<kind>-<r>.pt``: with
    ``adversary_seeds`` > 1 the candidate whose objective (the mean episode loss of its last updates; 0 when no
    episode finished) is largest; and the seconds every candidate's training took."""
    out, candidates = run.dir / f"{kind}-{r}.pt", round_candidates(cfg, run, r, kind)
    seconds = train_candidates(cfg, run, r, kind, candidates, log)
    if len(candidates) > 1:
        objectives = [provenance_of(file, kind)["final_episode_loss"] or 0.0 for file in candidates]
        best = int(np.argmax(objectives))
        log(f"[train-learner {run.name}] round {r}: {'f' if kind == 'adversary' else 'timing f'}_{r} is candidate "
            f"{best} of {len(candidates)} (objectives " + ", ".join(f"{o:.1f}" for o in objectives) + ")", flush=True)
        shutil.copyfile(candidates[best], out)
    return out, seconds


def train_candidates(cfg: LearnerConfig, run: LearnerRun, r: int, kind: str, candidates: list[Path], log) -> float:
    """Train (or keep, when an interruption left them finished) the ``candidates`` of round ``r`` against pi_r, each
    with its seed (warm-started from the previous round's with ``warm_start``); the seconds their trainings took."""
    init = str(run.dir / f"{kind}-{r - 1}.pt") if cfg.warm_start and r > 1 else ""
    timing = dataclasses.asdict(run.timing) if kind == "timing-adversary" else {}
    wanted = [AdversaryConfig(env=cfg.env, mode="clean" if timing else run.mode, eps=cfg.eps, **timing,
                              victim=str(run.policy_file(r)), expert=cfg.expert, steps=cfg.adversary_steps,
                              seed=seeds.round_adversary(cfg.seed, r, k), init=init, out=str(file))
               for k, file in enumerate(candidates)]
    # one finished before an interruption is kept: the same seed against the same pi_r gives the same file
    ready_adversaries(wanted, False, log, cfg.workers, cfg.address)
    return sum(provenance_of(file, kind)["train_seconds"] for file in candidates)


def provenance_of(file: Path, kind: str) -> dict:
    return (load_adversary(file) if kind == "adversary" else load_timing_adversary(file)).meta["provenance"]


def strongest_on(cfg: LearnerConfig, run: LearnerRun, r: int, options: list[tuple[str, str]], log
                 ) -> tuple[str, str]:
    """The (attack, adversary file) of ``options`` under which pi_r disagrees most with the expert: the paper's
    objective, the summed squared disagreement per episode, averaged over ``eval_episodes`` episodes that every
    option plays alike (:func:`seeds.round_judging`)."""
    learner, objectives = run.learner(r), []
    for name, file in options:
        attack = make_attack(name, run.layout, cfg.eps, victim=learner, expert=run.expert, adversary=file or None,
                             mode=run.mode)
        traj = run.rollout(learner, attack, run.mode, cfg.eval_episodes, seeds.round_judging(cfg.seed, r))
        objectives.append(float(disagreement(traj.action, traj.expert_action).sum()) / len(traj.length))
    best = int(np.argmax(objectives))
    labels = [name + (f" {Path(file).name}" if file else "") for name, file in options]
    log(f"[train-learner {run.name}] round {r}: f_{r} is {labels[best]} (objectives on pi_{r}: "
        + ", ".join(f"{label} {o:.1f}" for label, o in zip(labels, objectives)) + ")", flush=True)
    return options[best]


def round_candidates(cfg: LearnerConfig, run: LearnerRun, r: int, kind: str) -> list[Path]:
    """The files of round ``r``'s trained ``kind`` adversaries: f_r itself, or the candidates it is chosen from."""
    if cfg.adversary_seeds == 1 and not (cfg.round_attacks and kind == "adversary"):
        return [run.dir / f"{kind}-{r}.pt"]
    return [run.dir / f"{kind}-{r}-seed{k}.pt" for k in range(cfg.adversary_seeds)]
