"""The arguments of ``aril train-learner``, in four parts: what is imitated and under which attack
(:class:`ImitationConfig`), how each learner is fitted (:class:`FitConfig`), how ARIL makes a round's
adversary (:class:`RoundAdversaryConfig`), and the run itself (:class:`LearnerConfig`'s own fields).

:class:`LearnerConfig` holds them flat, in that order: every ``key:=value`` command line, and every file's
recorded ``settings`` (:func:`aril_ros.provenance.settings_of`), reads as it did when the file was made.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from . import seeds
from .args import arg, comma_list
from .registry import ATTACKED_MODES, DEFAULT_ENV, MAX_EPS, calibrated_eps
from .timing import TimingBudget, timing_arg

ALGORITHMS = {"dagger": "none", "dart": "none", "dr": "random", "aril": "aril_a"}  # and the attack in the loop
ROUND_ATTACKS = ("spsa", "random")
"""Attacks that may be ARIL's f_t beside the trained adversaries (round_attacks:=): black-box, as ARIL-A is."""
MIX_ATTACKS = ("clean", "random", "fgsm", "fgsm_k", "spsa")
"""What pi_t may also collect under each round beside f_t (mix:=); the white-box ones attack the round's own
learner, whose weights the training has."""
SELECTIONS = ("own", "worst")
SOURCES = ("inprocess", "graph")


@dataclass
class ImitationConfig:
    """What is imitated, under which attack, for how many rounds."""

    algorithm: str = arg("dagger", "dagger: the learner collects | dart: the expert collects with Gaussian action "
                                   "noise sized by the learner's error (Laskey et al. 2017) | dr: dagger under random "
                                   "+-eps perturbations (domain randomisation) | aril: dagger under ARIL-A, retrained "
                                   "against each learner (the paper's Algorithm 1)")
    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    expert: str = arg("expert", "the expert that labels the true states: a bundled name or a policy file")
    mode: str = arg("sensory", "dr and aril: sensory or physical perturbations, or clean with a timing budget "
                               "(timing alone; dagger and dart collect clean)")
    eps: float = arg(0.0, "dr and aril: the budget (0: the calibrated eps for env and mode, bundled with aril_ros)",
                     low=0.0, high=MAX_EPS)
    rounds: int = arg(10, "rounds of collecting and refitting after round 0 (expert demonstrations)", low=0, high=1000)
    episodes: int = arg(5, "episodes collected per round (1000 steps each)", low=1, high=100_000)
    data: str = arg("", "comma-separated run logs (.mcap) or Minari datasets from aril export, collected by anyone: "
                        "their (observation seen, expert action) pairs join round 0's demonstrations")
    delay: int = timing_arg("delay", "dr and aril, in the loop: dr's rounds draw it at random, aril's are timed by a "
                                     "timing adversary trained against each learner")
    drop: float = timing_arg("drop", "dr and aril, in the loop")
    action_delay: int = timing_arg("action_delay", "dr and aril, in the loop")
    mix: str = arg("", "dr and aril, beyond the paper: attacks (comma-separated: clean, random, fgsm, fgsm_k, spsa) "
                       "under which pi_t also collects each round, beside f_t, as many episodes each on the same env "
                       "seeds; all their pairs join the aggregated data set")
    select: str = arg("own", "which pi_t is returned: own (the paper's: the best return under its own round's f_t) or "
                             "worst (the best of its worst return over f_t and every mix:= attack, on the round's "
                             "episodes)")


@dataclass
class FitConfig:
    """How each learner is fitted on the aggregated data set."""

    hidden: int = arg(64, "width of the learner's two hidden layers", low=1, high=4096)
    epochs: int = arg(20, "passes over the aggregated data per fit", low=0, high=100_000)
    lr: float = arg(1e-3, "Adam learning rate (the paper's appendix)", low=0.0, high=1.0)
    batch: int = arg(256, "minibatch size", low=1, high=10**7)


@dataclass
class RoundAdversaryConfig:
    """ARIL: how each round's adversary f_t is made against pi_t (:mod:`aril_ros.aril_rounds`)."""

    adversary_steps: int = arg(300_000, "aril: PPO steps of each round's adversary", low=0, high=10**9)
    warm_start: bool = arg(False, "aril: each round's adversary starts from the previous round's (f_{t-1}) instead of "
                                  "fresh weights, so it keeps up with a learner that changes a little per round")
    adversary_seeds: int = arg(1, "aril: f_t is the strongest of this many adversaries trained against pi_t with "
                                  "different seeds (the largest objective at the end of its training): a closer "
                                  "argmax over adversaries, since one PPO run may miss the exploit another finds",
                                  low=1, high=100)
    workers: int = arg(1, "aril with adversary_seeds:=N: the candidates trained side by side on this many CPUs of a "
                          "local Ray (1: one after the other in this process); the files are the same either way",
                       low=1, high=1024)
    address: str = arg("", "aril: train the candidates on this Ray cluster instead (<head ip>:6379, or auto)")
    round_attacks: str = arg("", "aril: black-box attacks (comma-separated: spsa, random) that compete with the "
                                 "trained adversaries for f_t; then every candidate is judged by pi_t's mean episode "
                                 "disagreement with the expert under it (the paper's objective) on eval_episodes "
                                 "episodes, and the largest is f_t")


# dataclasses order fields from the last base to the first: the parts' arguments keep the order they were made in
@dataclass
class LearnerConfig(RoundAdversaryConfig, FitConfig, ImitationConfig):
    """Arguments of ``aril train-learner``."""

    eval_episodes: int = arg(5, "dr and aril: episodes of each learner's clean evaluation "
                                f"(env seeds {seeds.LEARNER_EVAL}...)", low=1, high=100_000)
    seed: int = arg(0, "seed of the fits, noise and adversaries; the rounds collect in the seed's training block "
                       "(aril_ros.seeds.collection(seed, round))", low=0, high=999)
    run_dir: str = arg("", "the run directory (default runs/<algorithm>-<env>[-<mode>]); an existing one is resumed")
    out: str = arg("", "where to write the selected policy (default runs/<algorithm>-<env>[-<mode>].pt)")
    threads: int = arg(1, "torch threads", low=1, high=256)
    source: str = arg("inprocess", "where rounds are collected: inprocess (the engine, fast) or graph (through the "
                                   "ROS 2 nodes of the installed ROS side, recorded to <run_dir>/round-<r>.mcap and "
                                   "loaded back); the same seeds give the same data set")


def timing_in_loop(cfg: LearnerConfig) -> TimingBudget:
    """The timing budget played in the loop's rounds (none: all zero)."""
    return TimingBudget(cfg.delay, cfg.drop, cfg.action_delay)


def checked(cfg: LearnerConfig) -> LearnerConfig:
    """``cfg`` with its eps filled in from the calibration when unset; a ValueError for what cannot run."""
    if cfg.algorithm not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {cfg.algorithm!r}; choose one of {', '.join(ALGORITHMS)}")
    timed = timing_in_loop(cfg).any  # and a budget out of range refused
    if ALGORITHMS[cfg.algorithm] == "none" and timed:
        raise ValueError(f"a timing budget (delay:=, drop:=, action_delay:=) is played in dr's and aril's loops; "
                         f"{cfg.algorithm} collects clean")
    if ALGORITHMS[cfg.algorithm] != "none" and not (cfg.mode == "clean" and timed):
        if cfg.mode not in ATTACKED_MODES:
            raise ValueError(f"{cfg.algorithm} needs mode:=sensory or mode:=physical (or clean with a timing budget), "
                             f"got {cfg.mode!r}")
        if cfg.eps == 0:
            cfg = dataclasses.replace(cfg, eps=calibrated_eps(cfg.env, cfg.mode))
        if not cfg.eps > 0:
            raise ValueError(f"eps:= must be > 0, got {cfg.eps}")
    if cfg.rounds < 1:
        raise ValueError("rounds:= must be >= 1")
    if cfg.adversary_seeds < 1:
        raise ValueError(f"adversary_seeds:= must be >= 1, got {cfg.adversary_seeds}")
    for name in comma_list(cfg.round_attacks):
        if name not in ROUND_ATTACKS:
            raise ValueError(f"round_attacks:= takes black-box attacks ({', '.join(ROUND_ATTACKS)}), got {name!r}")
    if cfg.round_attacks and (cfg.algorithm != "aril" or cfg.warm_start):
        raise ValueError("round_attacks:= is for algorithm:=aril without warm_start (which needs a learned f_{t-1})")
    for name in comma_list(cfg.mix):
        if name not in MIX_ATTACKS:
            raise ValueError(f"mix:= takes {', '.join(MIX_ATTACKS)}, got {name!r}")
    if cfg.mix and (ALGORITHMS[cfg.algorithm] == "none" or cfg.mode not in ATTACKED_MODES):
        raise ValueError(f"mix:= adds attacked collections to dr's and aril's rounds in mode:=sensory or physical "
                         f"(got algorithm:={cfg.algorithm} mode:={cfg.mode})")
    if cfg.mix and timed:
        raise ValueError("mix:= collects untimed: give it without a timing budget (delay:=, drop:=, action_delay:=)")
    if cfg.select not in SELECTIONS:
        raise ValueError(f"select:= must be one of {', '.join(SELECTIONS)}, got {cfg.select!r}")
    if cfg.select == "worst" and not cfg.mix:
        raise ValueError("select:=worst judges each learner over f_t and the mix:= attacks: name them in mix:=")
    if cfg.source not in SOURCES:
        raise ValueError(f"source:= must be one of {', '.join(SOURCES)}, got {cfg.source!r}")
    if cfg.source == "graph" and cfg.algorithm == "dart":
        raise ValueError("dart collects with a noisy expert, which has no policy node: use source:=inprocess")
    return cfg
