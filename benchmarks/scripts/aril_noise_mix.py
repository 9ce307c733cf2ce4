"""ARIL with DR's noise beside its adversary (issue 14's next experiment after fresh round adversaries): each round
collects the bundled ARIL's episodes under the round's adversary and as many again under random ±eps noise, so the
learner sees the adversary's corners and the whole box. Algorithm 1 otherwise unchanged (the bundled settings:
500k-step round adversaries warm-started from the round before); selection as bundled (the round's adversary return).

    .venv/bin/python benchmarks/scripts/aril_noise_mix.py env:=Swimmer-v5 mode:=physical eps:=0.005 \
        run_dir:=results/i14-fresh/aril-noise-Swimmer-v5-physical out:=results/i14-fresh/aril-noise-Swimmer-v5-physical.pt

Every train-learner argument is taken; the run directory resumes like train-learner's. Judge the result
with ``benchmarks/scripts/adversary-seeds.sh`` (ARIL-A seeds 0, 1, 2) and ``aril-fresh-worst.sh``.
"""
from __future__ import annotations

import sys

from aril_ros import dagger, seeds
from aril_ros.args import parse_args
from aril_ros.attacks import make_attack
from aril_ros.dataset import DaggerDataset

ALGORITHM_COLLECT = dagger.collect


def collect_with_noise(cfg, run, r, adversary_file):
    """The round's own collection, then (r > 0) the same learner on the same env seeds under random noise."""
    record, part = ALGORITHM_COLLECT(cfg, run, r, adversary_file)
    if r == 0:
        return record, part
    noise = run.rollout(run.learner(r), make_attack("random", run.layout, cfg.eps), run.mode, cfg.episodes,
                        seeds.collection(cfg.seed, r))
    record["noise_return"] = float(noise.returns.mean())
    return record, DaggerDataset.concatenate([part, DaggerDataset.from_trajectories(noise)])


def main(argv):
    defaults = dict(algorithm="aril", adversary_steps=500_000, warm_start=True)
    cfg = parse_args(dagger.LearnerConfig, [*(f"{k}:={v}" for k, v in defaults.items()), *argv])
    dagger.collect = collect_with_noise
    dagger.train_learner(cfg)


if __name__ == "__main__":
    main(sys.argv[1:])
