"""Which env seeds each use takes, so that no training ever runs on an evaluation's episodes.

Episode ``i`` of a run with first seed ``s`` resets its env with ``s + i`` (and draws its attack
noise from ``np.random.default_rng([s, i])``). The evaluation ranges below (1000 episodes each) never
overlap one another, and every training collects at or above ``TRAINING``, so no evaluation shares an
episode with a training: training seed ``k`` owns a block of ``SEED_BLOCK`` env seeds, in which
``train-learner``'s rounds (BC's demonstrations are its round 0) and ``train-adversary`` take disjoint
slices. A user's own ``aril eval`` / ``run_graph.py`` runs start at ``USER`` (0) unless told otherwise.

Files trained before this scheme (the bundled policies' provenance says which command made them)
took their collection seeds from ``seed*100000 + round*1000`` and BC's from ``seed*1000``.
"""
from __future__ import annotations

USER = 0
"""``aril eval`` and ``run_graph.py``: episodes 0, 1, ... unless ``seed:=`` says otherwise."""
CALIBRATION = 1_000
"""``aril calibrate-eps``: 1000..1999."""
ATTACK_TABLE = 2_000
"""``aril attack-table``: 2000..2999."""
DEFENSE_TABLE = 3_000
"""``aril defense-table`` and ``aril report`` (every table cell and sweep point): 3000..3999."""
SCORECARD = 4_000
"""``aril scorecard``: 4000..4999 (every cell the same episodes)."""
SCAN = 5_000
"""``aril scan-adversary``: 5000..5999 (every point and the clean run the same episodes)."""
SURROGATE = 6_000
"""The black-box pipeline (:mod:`aril_ros.verdict`): the episodes its surrogate's victim drives, 6000..6499."""
SCREENING = 6_500
"""The black-box pipeline: the episodes on which the zoo's adversaries are screened, 6500..6999."""
VALIDATION = 8_000
"""``aril validate-defense`` (the defense ARIL-V): the episodes on which its candidates are judged, 8000..8999."""
SELECTION = 10_000
"""Keeping the best during training (experts, GAIL, BC's check): 10000..10999."""
GAIL_DEMOS = 20_000
"""GAIL's clean expert demonstrations: 20000..20999."""
LEARNER_EVAL = 500_000
"""train-learner's clean evaluation of each round's learner (dr, aril): 500000..500999."""

TRAINING = 1_000_000
"""Everything a training collects lies at or above this."""
SEED_BLOCK = 1_000_000
"""Env seeds per training seed: training seed ``k`` collects in ``[TRAINING + k*SEED_BLOCK, + SEED_BLOCK)``."""
ROUND_BLOCK = 10_000
"""Env seeds per round of ``train-learner`` inside a training seed's block (round ``r``: slice ``r``)."""
ROUND_CANDIDATE_STRIDE = 1_000_000
"""Training seeds apart of a round's candidate adversaries (``train-learner adversary_seeds:=N``): candidate ``k``
of round ``r`` trains with ``round_weights(seed, r) + k * ROUND_CANDIDATE_STRIDE``, far above the round seeds of
every training seed below 1000, so no two share their env seeds."""
ROUND_JUDGING = 5_000
"""Offset inside a round's slice where ``train-learner round_attacks:=`` judges the round's candidate attacks on
pi_r (after the round's own collection, which takes its first ``episodes`` seeds)."""
VALIDATION_ADVERSARY = 3
"""The training seed of ``aril validate-defense``'s ARIL-A against each candidate: the tables' ARIL-As train with
seeds 0..2 (a bundled one is the strongest of three), so the judge that chooses a learner is none of those that
score it."""
ADVERSARY_SLICE = 500_000
"""Offset inside a training seed's block where ``train-adversary`` draws its episodes (after the rounds)."""


def training_block(seed: int) -> int:
    """The first env seed of training seed ``seed``'s block."""
    if seed < 0:
        raise ValueError(f"training seeds are >= 0, got {seed}")
    return TRAINING + seed * SEED_BLOCK


def collection(seed: int, round_: int) -> int:
    """First env seed of round ``round_`` of ``train-learner`` (BC's demonstrations: round 0)."""
    return training_block(seed) + round_ * ROUND_BLOCK


def round_judging(seed: int, round_: int) -> int:
    """First env seed of the episodes on which round ``round_``'s candidate attacks are judged (every candidate
    the same episodes)."""
    return collection(seed, round_) + ROUND_JUDGING


def adversary_training(seed: int) -> int:
    """First env seed of ``train-adversary`` with ``seed:=seed`` (it resets one env per new episode)."""
    return training_block(seed) + ADVERSARY_SLICE


def round_weights(seed: int, round_: int) -> int:
    """The torch seed of round ``round_``'s fit and (ARIL) adversary in ``train-learner`` with ``seed:=seed``
    (weights and minibatches, not env seeds: the round's adversary, trained with ``seed:=`` this value,
    resets its envs in that training seed's block, which no evaluation shares)."""
    return seed * 1000 + round_


def round_adversary(seed: int, round_: int, candidate: int = 0) -> int:
    """The training seed of candidate ``candidate`` of round ``round_``'s adversary in ``train-learner`` with
    ``seed:=seed``; candidate 0 is :func:`round_weights` (the only one when a round trains one adversary)."""
    return round_weights(seed, round_) + candidate * ROUND_CANDIDATE_STRIDE
