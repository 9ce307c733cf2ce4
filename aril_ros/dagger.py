"""Interactive imitation by rounds: DAgger (Ross et al., 2011), and with an attack in the loop,
domain randomisation (``attack:=random``) and ARIL (``attack:=aril_a``, the paper's Algorithm 1).

Round 0 collects expert demonstrations (DAgger's beta_0 = 1). Round r >= 1 runs the current learner
pi_r (through the attack f_r in ``mode``, where f_r is retrained against pi_r for ARIL-A), labels
every visited *true* state with the expert, adds the pairs (observation pi_r saw, expert action) to
the aggregated data set (follow the leader: nothing is ever dropped) and fits pi_{r+1} on all of it
from scratch. Round ``rounds`` only runs pi_rounds. A round's run is also its learner's evaluation
(under that round's attack): the returned policy is the pi_r with the best return in its own round,
because the analysis of DAgger and the paper's theorem bound the *best* pi_i, not the last.

:func:`train_learner` reads top to bottom: check the settings, open (or resume) the run directory
(:mod:`aril_ros.learner_run`), then per round train its adversary (:mod:`aril_ros.aril_rounds`), collect
with the run's collector (:mod:`aril_ros.collectors`), fit the next learner, and record; finally select.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import torch

from . import seeds
from .args import comma_list
from .aril_rounds import RoundAdversary, train_round_adversary
from .collectors import Collector, RoundSpec, collector_for
from .dataset import DaggerDataset, load_dagger_dataset
from .learner_config import LearnerConfig, checked
from .learner_run import LearnerRun


def train_learner(cfg: LearnerConfig, log=print, collector: Collector | None = None) -> Path:
    """Run (or resume) the rounds, each collected by ``collector`` (default: the one ``cfg`` names,
    :func:`~aril_ros.collectors.collector_for`); write the selected policy to ``cfg.out`` and return its path."""
    cfg = checked(cfg)
    torch.set_num_threads(cfg.threads)
    run, collector = LearnerRun(cfg, log), collector or collector_for(cfg)
    for r in range(len(run.rounds), cfg.rounds + 1):
        started = time.time()
        adversary = train_round_adversary(cfg, run, r, log)
        adversary_seconds = time.time() - started
        record, part = collect(collector, cfg, run, r, adversary)
        if r > 0 and cfg.mix:
            part = collect_mix(collector, cfg, run, r, record, part)
        if r == 0 and cfg.data:
            part = given_data(cfg, part, record)
        if r < cfg.rounds:
            record.update(run.fit_next(r, part))
        record["seconds"] = round(time.time() - started, 1)
        if r > 0 and (run.attack == "aril_a" or adversary.timing_file):
            record.update(adversary_seconds=round(adversary_seconds, 1), adversary_cpu_seconds=adversary.cpu_seconds)
        run.finish_round(record)
        log(run.round_line(record), flush=True)
    return select_best(cfg, run, log)


def collect(collector: Collector, cfg: LearnerConfig, run: LearnerRun, r: int, adversary: RoundAdversary
            ) -> tuple[dict, DaggerDataset]:
    """Run round ``r`` with ``collector``: the expert's clean demonstrations in round 0, then pi_r under the round's
    attack (its run is also its evaluation; dr and aril judge it clean too); the round's record and its (observation
    seen, expert action) pairs."""
    attack = adversary.attack if r > 0 else "none"
    timed = r > 0 and run.timing.any
    spec = RoundSpec(env=cfg.env, mode=run.mode if r > 0 else "clean", attack=attack,
                     eps=cfg.eps if attack != "none" else 0.0, policy=cfg.expert if r == 0 else str(run.policy_file(r)),
                     expert=cfg.expert, attack_file=adversary.file, episodes=cfg.episodes,
                     seed=seeds.collection(cfg.seed, r), record=run.dir / f"round-{r}.mcap",
                     **({"delay": run.timing.delay, "drop": run.timing.drop, "action_delay": run.timing.action_delay,
                         "timing": run.timing_chooser, "timing_file": adversary.timing_file} if timed else {}))
    learner = run.learner(r)
    collected = collector(run, r, learner, spec)
    record = {"round": r, **({"attack": attack} if attack != run.attack and r > 0 else {}), **collected.figures,
              "return": float(collected.returns.mean()), "return_std": float(collected.returns.std()),
              "expert_loss": collected.expert_loss}
    if r > 0 and (attack != "none" or timed):
        clean = run.rollout(learner, None, "clean", cfg.eval_episodes, seeds.LEARNER_EVAL)
        record["clean_return"] = float(clean.returns.mean())
    return record, collected.data


def collect_mix(collector: Collector, cfg: LearnerConfig, run: LearnerRun, r: int, record: dict,
                part: DaggerDataset) -> DaggerDataset:
    """Beyond the paper: pi_r also collects under each ``mix:=`` attack, on the round's own env seeds, so its data
    covers the states DR's noise, the gradient attacks or a clean run reach beside those f_r drives it to (a learner
    robust to its own adversary stayed open to query attacks: results/aril_a_tuning.md); each one's return is in
    the round's record (``mix``), what ``select:=worst`` judges by."""
    learner, parts = run.learner(r), [part]
    for name in comma_list(cfg.mix):
        spec = RoundSpec(env=cfg.env, mode="clean" if name == "clean" else run.mode,
                         attack="none" if name == "clean" else name, eps=0.0 if name == "clean" else cfg.eps,
                         policy=str(run.policy_file(r)), expert=cfg.expert, attack_file="", episodes=cfg.episodes,
                         seed=seeds.collection(cfg.seed, r), record=run.dir / f"round-{r}-{name}.mcap")
        collected = collector(run, r, learner, spec)
        record.setdefault("mix", {})[name] = float(collected.returns.mean())
        parts.append(collected.data)
    return DaggerDataset.concatenate(parts)


def given_data(cfg: LearnerConfig, part: DaggerDataset, record: dict) -> DaggerDataset:
    """Round 0's demonstrations and the pairs of the logs or datasets ``data:=`` names (their number recorded)."""
    given = load_dagger_dataset(comma_list(cfg.data), cfg.env)
    record["given_samples"] = len(given)
    return DaggerDataset.concatenate([part, given])


def select_best(cfg: LearnerConfig, run: LearnerRun, log) -> Path:
    """The theorem (like DAgger's) bounds the best of the learners pi_1..pi_R, each judged here by its
    own round: its return under the attack of that round (for ARIL, the adversary trained against it); with
    ``select:=worst``, by its worst return over that attack and every ``mix:=`` one (its own adversary alone judged
    it in ARIL's favour: the learner picked was often the one whose adversary failed, results/aril_a_tuning.md)."""
    best = max(run.rounds[1:], key=lambda rec: judged_return(cfg, rec))
    timing = f", timed by {run.timing_chooser} within {run.timing.described()}" if run.timing.any else ""
    attack = (f" ({run.mode}, {run.attack} eps {cfg.eps}{timing})" if run.attack != "none" else f" (clean{timing})")
    if cfg.select == "worst":
        selection = f"the learner with the best worst return in its own round{attack} and under {cfg.mix}"
    else:
        selection = "the learner with the best return in its own round" + attack
    out = run.save_selected(best["round"], selection)
    log(json.dumps({"out": str(out), "selected": f"pi_{best['round']}", "return": round(judged_return(cfg, best), 1)}))
    return out


def judged_return(cfg: LearnerConfig, record: dict) -> float:
    """A round's learner as ``select:=`` judges it: its return under the round's attack, or the worst of that and
    its returns under the ``mix:=`` attacks."""
    if cfg.select == "worst":
        return min(record["return"], *record.get("mix", {}).values())
    return record["return"]
