"""ARIL against a population (issue 14's next experiment after the noise mixture): each round collects the bundled
ARIL's episodes under the round's adversary f_r, as many again under random ±eps noise, and one episode under each
earlier round's adversary f_1..f_{r-1}, so the learner keeps answering the exploits it has already been shown (the
fictitious-play remedy for a learner that beats its last adversary and reopens an old hole). Selection is judged by
independent adversaries: every learner pi_1..pi_R under every round's adversary f_1..f_R and under random noise
(``eval_episodes`` each, on the selection seeds), and the learner with the best worst case over them is kept; the
matrix is written to ``<run_dir>/selection.json``. Algorithm 1 otherwise unchanged (500k-step round adversaries
warm-started from the round before).

    .venv/bin/python benchmarks/scripts/aril_population.py env:=Swimmer-v5 mode:=physical eps:=0.005 \
        run_dir:=results/i14-fresh/aril-pop-Swimmer-v5-physical out:=results/i14-fresh/aril-pop-Swimmer-v5-physical.pt

Every train-learner argument is taken; the run directory resumes like train-learner's. Judge the result
with ``benchmarks/scripts/adversary-seeds.sh`` (ARIL-A seeds 0, 1, 2) and ``aril-fresh-worst.sh``.
"""
from __future__ import annotations

import dataclasses
import json
import sys

from aril_noise_mix import collect_with_noise  # the sibling script (this script's folder is on the path)

from aril_ros import dagger, seeds
from aril_ros.args import parse_args
from aril_ros.attacks import make_attack
from aril_ros.dataset import DaggerDataset

POPULATION_SEEDS = 1_000
"""Offset, inside the round's block of env seeds, of the episodes under earlier adversaries (the round's own and
its noise episodes take the block's first seeds)."""


def adversary_file(run, r: int) -> str:
    return str(run.dir / f"adversary-{r}.pt")


def collect_with_population(cfg, run, r, round_adversary):
    """The round's own collection and its noise episodes (:func:`aril_noise_mix.collect_with_noise`), then (r > 0)
    one episode under each earlier round's adversary."""
    record, part = collect_with_noise(cfg, run, r, round_adversary)
    if r == 0:
        return record, part
    learner, first = run.learner(r), seeds.collection(cfg.seed, r)
    parts, earlier = [part], []
    for s in range(1, r):
        attack = make_attack("aril_a", run.layout, cfg.eps, victim=learner, expert=run.expert,
                             adversary=adversary_file(run, s), mode=run.mode)
        traj = run.rollout(learner, attack, run.mode, 1, first + POPULATION_SEEDS + s)
        parts.append(DaggerDataset.from_trajectories(traj))
        earlier.append(round(float(traj.returns.mean()), 1))
    record["earlier_adversary_returns"] = earlier
    return record, DaggerDataset.concatenate(parts)


def select_by_population(cfg, run, log):
    """The learner whose worst return under the rounds' adversaries and random noise is best."""
    learners, attacks = range(1, cfg.rounds + 1), ["random", *range(1, cfg.rounds + 1)]
    matrix = {}
    for r in learners:
        learner = run.learner(r)
        row = {}
        for a in attacks:
            attack = (make_attack("random", run.layout, cfg.eps) if a == "random" else
                      make_attack("aril_a", run.layout, cfg.eps, victim=learner, expert=run.expert,
                                  adversary=adversary_file(run, a), mode=run.mode))
            row[f"f_{a}" if a != "random" else a] = round(float(
                run.rollout(learner, attack, run.mode, cfg.eval_episodes, seeds.SELECTION).returns.mean()), 1)
        matrix[f"pi_{r}"] = {"worst": min(row.values()), **row}
        log(f"[aril-population {run.name}] pi_{r}: worst {matrix[f'pi_{r}']['worst']:.1f}  {row}", flush=True)
    (run.dir / "selection.json").write_text(json.dumps(matrix, indent=1))
    best = max(learners, key=lambda r: matrix[f"pi_{r}"]["worst"])
    cfg = dataclasses.replace(cfg, out=cfg.out or f"runs/{run.name}-population.pt")
    out = dagger.save_selected(cfg, run, best, f"the best worst case under every round's adversary and random noise "
                               f"({run.mode}, eps {cfg.eps}; {cfg.eval_episodes} episodes from env seed "
                               f"{seeds.SELECTION})", selection_matrix=matrix)
    log(json.dumps({"out": str(out), "selected": f"pi_{best}", "worst": matrix[f"pi_{best}"]["worst"]}))
    return out


def main(argv):
    defaults = dict(algorithm="aril", adversary_steps=500_000, warm_start=True)
    cfg = parse_args(dagger.LearnerConfig, [*(f"{k}:={v}" for k, v in defaults.items()), *argv])
    dagger.collect, dagger.select_best = collect_with_population, select_by_population
    dagger.train_learner(cfg)


if __name__ == "__main__":
    main(sys.argv[1:])
