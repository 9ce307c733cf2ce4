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

from .adversary import (AdversaryConfig, bundled_adversary_path, defense_adversary_path, load_adversary,
                        train_adversary)
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


def _trained_for(adversary: Path, eps: float) -> bool:
    return adversary.exists() and load_adversary(adversary).eps == eps


def _ready_adversary(adversary: Path, victim: str, env: str, mode: str, eps: float, expert: str, steps: int,
                     retrain: bool, log) -> None:
    """Train ``adversary`` against ``victim`` when it is missing, of another eps, or ``retrain``."""
    if retrain or not _trained_for(adversary, eps):
        train_adversary(AdversaryConfig(env=env, mode=mode, eps=eps, victim=victim, expert=expert, steps=steps,
                                        out=str(adversary)), log=log)
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
        _ready_adversary(adversary, cfg.policy, env, cfg.mode, eps, cfg.expert, cfg.adversary_steps, cfg.retrain, log)
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


DEFENSES = {"dagger": "DAgger", "aril": "ARIL", "dart": "DART", "dr": "DR", "gail": "GAIL", "bc": "BC"}
THREATS = ("random", "fgsm", "fgsm_k", "aril_a")


@dataclass
class DefenseTableConfig:
    """Arguments of ``aril defense-table``."""

    mode: str = arg("sensory", "sensory (Table 1) or physical (Table 2)")
    envs: str = arg(PAPER_ENVS_ARG, "comma-separated env ids")
    defenses: str = arg(",".join(DEFENSES), "comma-separated bundled learners (aril and dr: the ones of mode:=)")
    expert: str = arg("expert", "the expert")
    calibration: str = arg("results/eps_calibration.json", "where the eps per env and mode come from")
    episodes: int = arg(20, "deterministic episodes per cell")
    seed: int = arg(3000, "env seed of the first episode (and of the attack noise)")
    k: int = arg(10, "FGSM^k steps")
    adversary_steps: int = arg(1_000_000, "steps of the ARIL-A trained against each defense")
    adversary_dir: str = arg("", "where the adversaries against each defense go (default: the bundled ones, "
                                 "aril_ros/data/defense-adversary/); reused when they exist with the same eps")
    retrain: bool = arg(False, "train the adversaries even if they exist")
    horizon: int = arg(1000, "steps per episode")
    out: str = arg("", "output path without suffix (default: results/defenses_<mode>)")


def defense_table(cfg: DefenseTableConfig, log=print) -> dict:
    """Each defense's return under the strongest of random, FGSM, FGSM^k and an ARIL-A trained against
    that very defense; drops are from the clean DAgger learner's return (the paper's reference)."""
    from .experts import bundled_file

    stamp = _stamp("aril defense-table", cfg)
    defenses = _split(cfg.defenses)
    unknown = [d for d in defenses if d not in DEFENSES]
    if unknown:
        raise ValueError(f"unknown defenses {unknown}; choose from {', '.join(DEFENSES)}")
    fresh = []
    for env in _split(cfg.envs):
        eps = calibrated_eps(env, cfg.mode, cfg.calibration)
        common = dict(env=env, expert=cfg.expert, episodes=cfg.episodes, seed=cfg.seed, horizon=cfg.horizon, k=cfg.k)
        clean_results = {}

        def clean(policy: str) -> dict:  # the DAgger learner's is the reference and maybe a row too: run it once
            if policy not in clean_results:
                clean_results[policy] = evaluate(EvalConfig(policy=policy, mode="clean", **common))
            return clean_results[policy]

        reference = clean(str(bundled_file("dagger", env)))["mean_return"]
        cells = {}
        for defense in defenses:
            policy = str(bundled_file(defense, env, cfg.mode))
            adversary = (Path(cfg.adversary_dir) / f"{env}-{cfg.mode}-{defense}.pt" if cfg.adversary_dir
                         else defense_adversary_path(env, cfg.mode, defense))
            _ready_adversary(adversary, policy, env, cfg.mode, eps, cfg.expert, cfg.adversary_steps, cfg.retrain, log)
            results = {"none": clean(policy)}
            for threat in THREATS:
                results[threat] = evaluate(EvalConfig(policy=policy, mode=cfg.mode, attack=threat, eps=eps,
                                                      attack_file=str(adversary) if threat == "aril_a" else "",
                                                      **common))
            worst = min(THREATS, key=lambda t: results[t]["mean_return"])
            cells[defense] = {
                "clean": results["none"]["mean_return"], "clean_std": results["none"]["std_return"],
                "attacks": {t: {"mean": results[t]["mean_return"], "std": results[t]["std_return"]} for t in THREATS},
                "worst": worst, "mean": results[worst]["mean_return"], "std": results[worst]["std_return"],
                "drop": round(1.0 - results[worst]["mean_return"] / reference, 4) if reference else 0.0,
                "episodes": cfg.episodes, "eps": eps, "seeds": f"{cfg.seed}..{cfg.seed + cfg.episodes - 1}",
                "policy": policy.split("aril_ros/")[-1], "adversary": load_adversary(adversary).meta["provenance"],
                **stamp}
            log(f"[defense-table {cfg.mode}] {env} {DEFENSES[defense]}: clean {cells[defense]['clean']:.1f}, worst "
                f"{ROW_NAMES[worst]} {cells[defense]['mean']:.1f} ± {cells[defense]['std']:.1f}", flush=True)
        fresh.append({"env": env, "dagger_clean": reference, "cells": cells})
    out = cfg.out or f"results/defenses_{cfg.mode}"
    old_path = Path(out).with_suffix(".json")
    old = json.loads(old_path.read_text()) if old_path.exists() else {}
    if old.get("mode") == cfg.mode:  # defenses not rerun keep their cells
        for row in fresh:
            kept = next((r["cells"] for r in old["rows"] if r["env"] == row["env"]), {})
            row["cells"] = {d: row["cells"].get(d, kept.get(d)) for d in DEFENSES if d in row["cells"] or d in kept}
    rows = _merge(out, lambda r: (r["env"],), fresh, lambda old: old.get("mode") == cfg.mode)
    envs = [r["env"] for r in rows]
    by_env = {r["env"]: r for r in rows}
    shown = [d for d in DEFENSES if all(d in by_env[e]["cells"] for e in envs)]
    payload = {"mode": cfg.mode, "rows": rows,
               "overall_drop": {d: round(sum(by_env[e]["cells"][d]["drop"] for e in envs) / len(envs), 4)
                                for d in shown}}
    table = "Table 1" if cfg.mode == "sensory" else "Table 2"
    lines = [f"# {table} ({cfg.mode} attacks), Robust IL rows", "",
             "Each defense's return under the strongest of random, FGSM, FGSM^k and an ARIL-A trained against that "
             "defense (in brackets), mean ± std over deterministic episodes; the drop is from the clean DAgger "
             "learner. Each cell's seeds, clean return, every attack's figure and the command are in the JSON.", "",
             "| defense | " + " | ".join(f"{e} (eps {by_env[e]['cells'][shown[0]]['eps']:g})" for e in envs)
             + " | overall |", "|---|" + "---|" * len(envs) + "---|",
             "| DAgger, clean | " + " | ".join(f"{by_env[e]['dagger_clean']:.0f}" for e in envs) + " | 0% |"]
    for d in shown:
        row = [f"{c['mean']:.0f} ± {c['std']:.0f} ({-100 * c['drop']:+.1f}%, {ROW_NAMES[c['worst']]})"
               for c in (by_env[e]["cells"][d] for e in envs)]
        lines.append(f"| {DEFENSES[d]} | " + " | ".join(row) + f" | {-100 * payload['overall_drop'][d]:+.1f}% |")
    _write(out, payload, "\n".join(lines) + "\n")
    return payload
