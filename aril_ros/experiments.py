"""The experiments behind the committed tables in ``results/`` (each as JSON and markdown).

- :func:`calibrate_eps` (``aril calibrate-eps``): the paper's rule for the budget — per env and
  mode, the largest eps of a grid at which FGSM costs the victim at most ``max_drop`` (40%) of its
  clean return.
- :func:`attack_table` (``aril attack-table``): the paper's Table 1 (sensory) / Table 2 (physical)
  *Adversary* rows — the victim's return clean and under random, FGSM, FGSM^k and ARIL-A at the
  calibrated eps, mean ± std over deterministic episodes, and the drop from clean.

Every JSON names the command, the git revision and the seeds that produced it.
"""
from __future__ import annotations

import datetime
import json
from dataclasses import dataclass
from pathlib import Path

from .adversary import AdversaryConfig, bundled_adversary_path, load_adversary, train_adversary
from .args import arg, command_line
from .attacks import calibrated_eps
from .evaluation import EvalConfig, evaluate
from .experts import git_revision

PAPER_ENVS_ARG = "HalfCheetah-v5,Ant-v5,Swimmer-v5"
BUNDLED_LEARNER = "dagger"  # the victim of the attack tables (the paper attacks DAgger learners)


def _split(text: str) -> list[str]:
    return [x for x in text.split(",") if x]


def _write(out: str, payload: dict, markdown: str) -> None:
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.with_suffix(".json").write_text(json.dumps(payload, indent=1) + "\n")
    path.with_suffix(".md").write_text(markdown)


def _stamp(prog: str, cfg) -> dict:
    return {"command": command_line(prog, cfg), "git_revision": git_revision(),
            "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}


@dataclass
class CalibrationConfig:
    """Arguments of ``aril calibrate-eps``."""

    envs: str = arg(PAPER_ENVS_ARG, "comma-separated env ids")
    modes: str = arg("sensory,physical", "comma-separated modes")
    policy: str = arg(BUNDLED_LEARNER, "the victim (the learner under attack): a bundled name or a policy file")
    expert: str = arg("expert", "the expert")
    grid: str = arg("0.002,0.005,0.01,0.02,0.05,0.1,0.2", "comma-separated eps values to try")
    max_drop: float = arg(0.4, "the largest tolerated FGSM drop from clean return (the paper: 40%)")
    episodes: int = arg(10, "deterministic episodes per cell")
    seed: int = arg(1000, "env seed of the first episode")
    horizon: int = arg(1000, "steps per episode")
    out: str = arg("results/eps_calibration", "output path without suffix (.json and .md are written)")


def _merge(out: str, key, fresh: list[dict], same_run) -> list[dict]:
    """``fresh`` rows plus the rows of an existing ``out.json`` that ``same_run`` accepts and ``fresh``
    does not replace (same ``key``), so a table can be filled in env by env."""
    path = Path(out).with_suffix(".json")
    old = json.loads(path.read_text()) if path.exists() else None
    kept = [] if old is None or not same_run(old) else old["rows"]
    replaced = {key(r) for r in fresh}
    return sorted([r for r in kept if key(r) not in replaced] + fresh, key=lambda r: _env_order(r["env"]) + key(r)[1:])


def _env_order(env: str) -> tuple:
    paper = _split(PAPER_ENVS_ARG)
    return (paper.index(env) if env in paper else len(paper), env)


def calibrate_eps(cfg: CalibrationConfig, log=print) -> dict:
    """Sweep the grid for each env and mode; rows of other envs/modes already in ``cfg.out`` (same
    victim and rule) are kept, each with the command that made it."""
    fresh = []
    grid = sorted(float(e) for e in _split(cfg.grid))
    stamp = _stamp("aril calibrate-eps", cfg)
    for env in _split(cfg.envs):
        common = dict(env=env, policy=cfg.policy, expert=cfg.expert, episodes=cfg.episodes, seed=cfg.seed,
                      horizon=cfg.horizon)
        clean = evaluate(EvalConfig(mode="clean", **common))["mean_return"]
        for mode in _split(cfg.modes):
            sweep = []
            for eps in grid:
                result = evaluate(EvalConfig(mode=mode, attack="fgsm", eps=eps, **common))
                drop = 1.0 - result["mean_return"] / clean if clean else 0.0
                sweep.append({"eps": eps, "mean": result["mean_return"], "std": result["std_return"],
                              "drop": round(drop, 4)})
                log(f"[calibrate-eps] {env} {mode} eps={eps}: FGSM return {result['mean_return']:.1f} "
                    f"(clean {clean:.1f}, drop {100 * drop:.1f}%)", flush=True)
            # ascending, up to the first eps that breaks the rule (a larger eps can "help" by chance)
            allowed = []
            for s in sweep:
                if s["drop"] > cfg.max_drop:
                    break
                allowed.append(s["eps"])
            fresh.append({"env": env, "mode": mode, "clean": clean, "sweep": sweep,
                          "chosen_eps": allowed[-1] if allowed else grid[0],
                          "rule": f"largest eps before FGSM first drops the return by more than {cfg.max_drop:.0%}"
                          if allowed else "even the smallest eps broke the rule: the smallest tried",
                          "episodes": cfg.episodes, "seeds": f"{cfg.seed}..{cfg.seed + cfg.episodes - 1}", **stamp})
    rows = _merge(cfg.out, lambda r: (r["env"], r["mode"]), fresh,
                  lambda old: old.get("victim") == cfg.policy and old.get("max_drop") == cfg.max_drop)
    payload = {"victim": cfg.policy, "expert": cfg.expert, "max_drop": cfg.max_drop, "rows": rows}
    lines = [f"# eps calibration (victim: {cfg.policy})", "",
             f"FGSM return per eps (mean over deterministic episodes, drop from clean); chosen: the largest eps "
             f"before FGSM first costs more than {cfg.max_drop:.0%} of the clean return. Each row's command is in "
             "the JSON.", "",
             "| env | mode | clean | FGSM return per eps | chosen eps | episodes (seeds) |", "|---|---|---|---|---|---|"]
    for r in rows:
        cells = ", ".join(f"{s['eps']:g}: {s['mean']:.0f} ({-100 * s['drop']:+.0f}%)" for s in r["sweep"])
        lines.append(f"| {r['env']} | {r['mode']} | {r['clean']:.0f} | {cells} | **{r['chosen_eps']:g}** | "
                     f"{r['episodes']} ({r['seeds']}) |")
    _write(cfg.out, payload, "\n".join(lines) + "\n")
    return payload


@dataclass
class AttackTableConfig:
    """Arguments of ``aril attack-table``."""

    mode: str = arg("sensory", "sensory (Table 1) or physical (Table 2)")
    envs: str = arg(PAPER_ENVS_ARG, "comma-separated env ids")
    policy: str = arg(BUNDLED_LEARNER, "the victim: a bundled name or a policy file")
    expert: str = arg("expert", "the expert")
    calibration: str = arg("results/eps_calibration.json", "where the eps per env and mode come from")
    episodes: int = arg(20, "deterministic episodes per cell")
    seed: int = arg(2000, "env seed of the first episode (and of the attack noise)")
    k: int = arg(10, "FGSM^k steps")
    adversary_steps: int = arg(1_000_000, "ARIL-A training steps when no adversary file exists yet")
    retrain: bool = arg(False, "train ARIL-A even if a bundled adversary exists")
    adversary_dir: str = arg("runs", "where adversaries against a victim other than the bundled learner go")
    horizon: int = arg(1000, "steps per episode")
    out: str = arg("", "output path without suffix (default: results/attacks_<mode>)")


ATTACK_ROWS = ("none", "random", "fgsm", "fgsm_k", "aril_a")
ROW_NAMES = {"none": "clean", "random": "random", "fgsm": "FGSM", "fgsm_k": "FGSM^k", "aril_a": "ARIL-A"}


def attack_table(cfg: AttackTableConfig, log=print) -> dict:
    """Fill the Adversary rows for ``cfg.envs``; envs already in the output file (same mode and
    victim) are kept, every cell with the command that made it."""
    stamp = _stamp("aril attack-table", cfg)
    fresh = []
    for env in _split(cfg.envs):
        eps = calibrated_eps(env, cfg.mode, cfg.calibration)
        # against the bundled learner the adversary is bundled too (attack:=aril_a by name); else under runs/
        adversary = (bundled_adversary_path(env, cfg.mode) if cfg.policy == BUNDLED_LEARNER
                     else Path(cfg.adversary_dir) / f"adversary-{env}-{cfg.mode}-{Path(cfg.policy).stem}.pt")
        if cfg.retrain or not adversary.exists() or load_adversary(adversary).eps != eps:
            train_adversary(AdversaryConfig(env=env, mode=cfg.mode, eps=eps, victim=cfg.policy, expert=cfg.expert,
                                            steps=cfg.adversary_steps, out=str(adversary)), log=log)
        cells = {}
        for attack in ATTACK_ROWS:
            result = evaluate(EvalConfig(env=env, policy=cfg.policy, expert=cfg.expert,
                                         mode="clean" if attack == "none" else cfg.mode, attack=attack,
                                         eps=0.0 if attack == "none" else eps, k=cfg.k,
                                         attack_file=str(adversary) if attack == "aril_a" else "",
                                         episodes=cfg.episodes, seed=cfg.seed, horizon=cfg.horizon))
            clean = cells["none"]["mean"] if attack != "none" else result["mean_return"]
            cells[attack] = {"mean": result["mean_return"], "std": result["std_return"],
                             "episodes": cfg.episodes, "eps": result["eps"],
                             "seeds": f"{cfg.seed}..{cfg.seed + cfg.episodes - 1}",
                             "mean_expert_loss": result["mean_expert_loss"],
                             "drop": round(1.0 - result["mean_return"] / clean, 4) if clean else 0.0, **stamp}
            if attack == "aril_a":
                cells[attack]["adversary"] = load_adversary(adversary).meta["provenance"]
            log(f"[attack-table {cfg.mode}] {env} {ROW_NAMES[attack]}: {result['mean_return']:.1f} ± "
                f"{result['std_return']:.1f}", flush=True)
        fresh.append({"env": env, "cells": cells})
    rows = _merge(cfg.out or f"results/attacks_{cfg.mode}", lambda r: (r["env"],), fresh,
                  lambda old: (old.get("mode"), old.get("victim")) == (cfg.mode, cfg.policy))
    envs = [r["env"] for r in rows]
    cells = {r["env"]: r["cells"] for r in rows}
    payload = {"mode": cfg.mode, "victim": cfg.policy, "rows": rows,
               "overall_drop": {a: round(sum(cells[e][a]["drop"] for e in envs) / len(envs), 4)
                                for a in ATTACK_ROWS}}
    table = "Table 1" if cfg.mode == "sensory" else "Table 2"
    lines = [f"# {table} ({cfg.mode} attacks), Adversary rows — victim: {cfg.policy}", "",
             "Return, mean ± std over deterministic episodes, and the drop from clean; each cell's episodes, "
             "seeds and command are in the JSON.", "",
             "| attack | " + " | ".join(f"{e} (eps {cells[e]['fgsm']['eps']:g})" for e in envs) + " | overall |",
             "|---|" + "---|" * len(envs) + "---|"]
    for attack in ATTACK_ROWS:
        row = [f"{cells[e][attack]['mean']:.0f} ± {cells[e][attack]['std']:.0f}"
               + ("" if attack == "none" else f" ({-100 * cells[e][attack]['drop']:+.1f}%)") for e in envs]
        overall = "0%" if attack == "none" else f"{-100 * payload['overall_drop'][attack]:+.1f}%"
        lines.append(f"| {ROW_NAMES[attack]} | " + " | ".join(row) + f" | {overall} |")
    _write(cfg.out or f"results/attacks_{cfg.mode}", payload, "\n".join(lines) + "\n")
    return payload
