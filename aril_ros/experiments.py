"""The experiments behind the committed tables in ``results/`` (each as JSON and markdown).

- :func:`calibrate_eps` (``aril calibrate-eps``): the paper's rule for the budget — per env and
  mode, the largest eps of a grid at which FGSM costs the victim at most ``max_drop`` (40%) of its
  clean return. Its JSON is the bundled calibration (``aril_ros/data/eps_calibration.json``, what
  ``eps:=0`` reads), its markdown ``results/eps_calibration.md``.
- :func:`attack_table` (``aril attack-table``): the paper's Table 1 (sensory) / Table 2 (physical)
  *Adversary* rows — the victim's return clean and under random, FGSM, FGSM^k, SPSA^k, ARIL-A, FGSM^k by
  finite differences, FGSM^k on a surrogate and ARIL-A with query-time search at the calibrated eps, mean ± std
  over deterministic episodes, the drop from clean and, for the black-box attacks that query the victim, the queries per step.
- :func:`defense_table` (``aril defense-table``): the *Robust IL* rows — each defense under its worst
  attack.

Every cell comes from :func:`aril_ros.report.stats.summarise` and every worst attack from
:func:`aril_ros.report.stats.worst_attack`, as in ``aril report`` (which prints mean ± 95% interval where
these print mean ± std). Every JSON names the command and settings that produced it
(:func:`aril_ros.provenance.stamp`), the git revision and the seeds.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

from . import seeds
from .adversary import AdversaryConfig, load_adversary, ready_adversaries
from .envs import HORIZON
from .args import arg, comma_list
from .attacks import FGSMk
from .evaluation import EvalConfig, evaluate_all
from .policy import load_policy
from .provenance import cpu, portable, stamp
from .registry import (ATTACKED_MODES, ATTACKS, DEFAULT_POLICY, DEFENSES, DIRECTED_ROW, PAPER_ENVS,
                       SCORECARD_ATTACKS, SEARCH_ROW, TABLE_SEARCH, THREATS, adversary_path, bundled_file,
                       calibrated_eps, directed_adversary_path, row_attack, surrogate_path, check_name,
                       user_calibration)
from .report.stats import summarise, worst_attack
from .sweep import session
from .verdict import ready_surrogate

TRANSFER_ROW = "transfer"
"""FGSM^k on a surrogate fitted to the victim's answers (:func:`aril_ros.verdict.ready_surrogate`): black-box, and
the one attack that asks the victim nothing while it runs."""
FD_ROW = "fd_fgsm"
"""FGSM^k by finite differences (:class:`aril_ros.attacks.FiniteDifferenceFGSM`) at FGSM^k's iterations: the
black-box FGSM^k, two questions per perturbed entry an iteration."""
ATTACK_ROWS = ("none", *THREATS, FD_ROW, TRANSFER_ROW, SEARCH_ROW, DIRECTED_ROW)
"""The rows of the attack tables: clean, then each attack."""
KEPT_SETTINGS = ("policy", "expert", "calibration", "episodes", "seed", "k", "search", "horizon")
"""The settings a cell kept from an earlier run (``rows:=`` naming others) must share with the run: those that
change its figure or the table's other cells' meaning."""
ROW_NAMES = {**ATTACKS, SEARCH_ROW: SCORECARD_ATTACKS[SEARCH_ROW], FD_ROW: "FGSM^k by finite differences",
             DIRECTED_ROW: SCORECARD_ATTACKS[DIRECTED_ROW]}


def _cell(result: dict) -> dict:
    """An evaluation's cell (mean and std of its returns), as the tables' JSON stores it."""
    cell = summarise([result["returns"]])
    return {"mean": round(cell["mean"], 3), "std": round(cell["std"], 3)}


def _outputs(out: str, default: str) -> tuple[Path, Path]:
    """The JSON and markdown a table writes: ``<out>.json`` and ``<out>.md`` (``out`` unset: ``default``)."""
    path = Path(out or default)
    return path.with_suffix(".json"), path.with_suffix(".md")


def _write(json_path: Path, payload: dict, md_path: Path, markdown: str) -> None:
    for path in (json_path, md_path):
        path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(payload, indent=1) + "\n")
    md_path.write_text(markdown)


def _merge(path: Path, key, fresh: list[dict], same_run) -> list[dict]:
    """``fresh`` rows plus the rows of an existing JSON table at ``path`` that ``same_run`` accepts and
    ``fresh`` does not replace (same ``key``), so a table can be filled in env by env."""
    old = json.loads(path.read_text()) if path.exists() else None
    kept = [] if old is None or not same_run(old) else old["rows"]
    replaced = {key(r) for r in fresh}
    return sorted([r for r in kept if key(r) not in replaced] + fresh, key=lambda r: _env_order(r["env"]) + key(r)[1:])


def _env_order(env: str) -> tuple:
    return (PAPER_ENVS.index(env) if env in PAPER_ENVS else len(PAPER_ENVS), env)


@dataclass
class CalibrationConfig:
    """Arguments of ``aril calibrate-eps``."""

    envs: str = arg(",".join(PAPER_ENVS), "comma-separated env ids")
    modes: str = arg(",".join(ATTACKED_MODES), "comma-separated modes")
    policy: str = arg(DEFAULT_POLICY, "the victim (the learner under attack): a bundled name or a policy file")
    expert: str = arg("expert", "the expert")
    grid: str = arg("0.002,0.005,0.01,0.02,0.05,0.1,0.2", "comma-separated eps values to try")
    max_drop: float = arg(0.4, "the largest tolerated FGSM drop from clean return (the paper: 40%)", low=0.0, high=1.0)
    episodes: int = arg(10, "deterministic episodes per cell", low=1, high=100_000)
    seed: int = arg(seeds.CALIBRATION, "env seed of the first episode", low=0, high=2**31 - 1)
    horizon: int = arg(HORIZON, "steps per episode", low=1, high=1_000_000)
    workers: int = arg(2, "CPUs of the local Ray its evaluations run on as tasks (1: one after the other in this process)",
                       low=1, high=1024)
    address: str = arg("", "run the evaluations on this Ray cluster instead (<head ip>:6379, or auto)")
    out: str = arg("", "output path without suffix (.json and .md are written); unset: the user's calibration, "
                       "eps_calibration.{json,md} in the user data folder ($ARIL_DATA), which eps:=0 reads where "
                       "the bundled one has no row")


FINER = 5
"""Where even the grid's smallest eps breaks the rule, the calibration tries that eps halved this many times more
(down to 1/32 of it), so that the chosen eps keeps the rule."""


def calibrate_eps(cfg: CalibrationConfig, log=print) -> dict:
    """Sweep the grid for each env and mode; rows already in the output under the same rule are kept, each with
    the command that made it, except an env's rows of another victim (an env is calibrated against one)."""
    made = stamp("aril calibrate-eps", cfg)
    json_path, md_path = _outputs(cfg.out, str(user_calibration().with_suffix("")))
    fresh = []
    grid = sorted(float(e) for e in comma_list(cfg.grid))
    envs, modes = comma_list(cfg.envs), comma_list(cfg.modes)

    def job(env: str, mode: str, eps: float) -> dict:
        return asdict(EvalConfig(env=env, policy=cfg.policy, expert=cfg.expert, episodes=cfg.episodes, seed=cfg.seed,
                                 horizon=cfg.horizon, mode=mode, attack="fgsm" if mode != "clean" else "none", eps=eps))

    def evaluated(plan: list[tuple[str, str, float]]) -> dict:
        return dict(zip(plan, map(_cell, evaluate_all([job(*p) for p in plan], cfg.workers, cfg.address, log))))

    def drop(env: str, mode: str, eps: float) -> float:
        clean = cells[env, "clean", 0.0]["mean"]
        return 1.0 - cells[env, mode, eps]["mean"] / clean if clean else 0.0

    cells = evaluated([(env, "clean", 0.0) for env in envs]
                      + [(env, mode, eps) for env in envs for mode in modes for eps in grid])
    # a victim too fragile for the grid's smallest eps (Hopper's learner under physical attack): halvings below it
    cells.update(evaluated([(env, mode, grid[0] / 2 ** k) for env in envs for mode in modes
                            if drop(env, mode, grid[0]) > cfg.max_drop for k in range(1, FINER + 1)]))
    for env in envs:
        clean = cells[env, "clean", 0.0]["mean"]
        for mode in modes:
            sweep = []
            tried = sorted(eps for e, m, eps in cells if (e, m) == (env, mode))
            for eps in tried:
                cell = cells[env, mode, eps]
                sweep.append({"eps": eps, **cell, "drop": round(drop(env, mode, eps), 4)})
                log(f"[calibrate-eps] {env} {mode} eps={eps:g}: FGSM return {cell['mean']:.1f} "
                    f"(clean {clean:.1f}, drop {100 * drop(env, mode, eps):.1f}%)", flush=True)
            # ascending, up to the first eps that breaks the rule (a larger eps can "help" by chance)
            allowed = []
            for s in sweep:
                if s["drop"] > cfg.max_drop:
                    break
                allowed.append(s["eps"])
            fresh.append({"env": env, "mode": mode, "victim": cfg.policy, "clean": clean, "sweep": sweep,
                          "chosen_eps": allowed[-1] if allowed else tried[0],
                          "rule": f"largest eps before FGSM first drops the return by more than {cfg.max_drop:.0%}"
                          if allowed else "even the smallest eps broke the rule: the smallest tried",
                          "episodes": cfg.episodes, "seeds": f"{cfg.seed}..{cfg.seed + cfg.episodes - 1}", **made})
    # each row names its victim: a file holds envs calibrated against learners of their own (a user's), but an
    # env's modes are calibrated against one learner, so another victim for an env starts that env anew
    file_victim = json.loads(json_path.read_text())["victim"] if json_path.exists() else cfg.policy
    rows = _merge(json_path, lambda r: (r["env"], r["mode"]), fresh, lambda old: old.get("max_drop") == cfg.max_drop)
    for row in rows:
        row.setdefault("victim", file_victim)  # a row written before rows named theirs: the file's one
    envs_now = {row["env"] for row in fresh}
    rows = [row for row in rows if row["env"] not in envs_now or row["victim"] == cfg.policy]
    victims = sorted({row["victim"] for row in rows})
    payload = {"victim": victims[0] if len(victims) == 1 else "per row", "expert": cfg.expert,
               "max_drop": cfg.max_drop, "rows": rows}
    _write(json_path, payload, md_path, calibration_markdown(payload))
    return payload


def calibration_markdown(payload: dict) -> str:
    lines = [f"# eps calibration (victim: {payload['victim']})", "",
             f"FGSM return per eps (mean over deterministic episodes, drop from clean); chosen: the largest eps "
             f"before FGSM first costs more than {payload['max_drop']:.0%} of the clean return. Each row's command "
             "is in the JSON.", "",
             "| env | mode | victim | clean | FGSM return per eps | chosen eps | episodes (seeds) |",
             "|---|---|---|---|---|---|---|"]
    for r in payload["rows"]:
        cells = ", ".join(f"{s['eps']:g}: {s['mean']:.0f} ({-100 * s['drop']:+.0f}%)" for s in r["sweep"])
        kept = "" if r.get("rule", "").startswith("largest") else f" ({r['rule']})"
        lines.append(f"| {r['env']} | {r['mode']} | {r['victim']} | {r['clean']:.0f} | {cells} | **{r['chosen_eps']:g}**"
                     f"{kept} | {r['episodes']} ({r['seeds']}) |")
    return "\n".join(lines) + "\n"


@dataclass
class AttackTableConfig:
    """Arguments of ``aril attack-table``."""

    mode: str = arg("sensory", "sensory (Table 1) or physical (Table 2)")
    envs: str = arg(",".join(PAPER_ENVS), "comma-separated env ids")
    policy: str = arg(DEFAULT_POLICY, "the victim: a bundled name or a policy file")
    expert: str = arg("expert", "the expert")
    calibration: str = arg("", "where the eps per env and mode come from (unset: the bundled calibration, then the user's)")
    episodes: int = arg(20, "deterministic episodes per cell", low=1, high=100_000)
    seed: int = arg(seeds.ATTACK_TABLE, "env seed of the first episode (and of the attack noise)",
                    low=0, high=2**31 - 1)
    k: int = arg(0, "iterations of FGSM^k and of FGSM^k by finite differences (0: 10), and of SPSA^k (0: 5)",
                 low=0, high=1000)
    search: int = arg(TABLE_SEARCH, "candidates of ARIL-A's query-time search in its own row (0: no such row)",
                      low=0, high=1000)
    rows: str = arg("", f"comma-separated rows to run ({', '.join(ATTACK_ROWS)}; default: every one, "
                        "aril_a_search where search > 0); an env already in the output keeps its other rows when they "
                        f"were run with the same {', '.join(KEPT_SETTINGS)} on the same CPU model, else names what "
                        "differs")
    adversary_steps: int = arg(1_000_000, "ARIL-A training steps when no adversary file exists yet", low=1, high=10**9)
    retrain: bool = arg(False, "train ARIL-A even if a bundled adversary exists")
    adversary_dir: str = arg("runs", "where adversaries against a victim other than the bundled learner go")
    horizon: int = arg(HORIZON, "steps per episode", low=1, high=1_000_000)
    workers: int = arg(2, "CPUs of the local Ray its evaluations run on as tasks (1: one after the other in this process)",
                       low=1, high=1024)
    address: str = arg("", "run the evaluations on this Ray cluster instead (<head ip>:6379, or auto)")
    out: str = arg("", "output path without suffix (default: results/attacks_<mode>)")


def attack_table(cfg: AttackTableConfig, log=print) -> dict:
    """Fill the Adversary rows for ``cfg.envs``; envs already in the output file (same mode and
    victim) are kept, every cell with the command that made it, and so are an env's rows that ``rows:=`` leaves
    out."""
    made = stamp("aril attack-table", cfg)
    json_path, md_path = _outputs(cfg.out, f"results/attacks_{cfg.mode}")
    rows_of = table_rows(cfg)
    earlier = _earlier_cells(json_path, cfg, rows_of) if cfg.rows else {}
    files, jobs, wanted = {}, [], []  # files: per env, the file each row's attack reads
    for env in comma_list(cfg.envs):
        if "none" not in rows_of and "none" not in earlier.get(env, {}):
            raise ValueError(f"rows:={cfg.rows}: {json_path} has no clean row of {env} run with these settings to "
                             "take the drops from: add none to rows:=")
        eps = calibrated_eps(env, cfg.mode, cfg.calibration or None)
        # against the bundled learner the adversaries and the surrogate are bundled too (attack:=aril_a by name); else
        # under runs/
        own = cfg.policy == DEFAULT_POLICY

        def made_for(kind: str, bundled: Path) -> Path:
            return bundled if own else Path(cfg.adversary_dir) / f"{kind}-{env}-{cfg.mode}-{Path(cfg.policy).stem}.pt"

        adversary = made_for("adversary", adversary_path(env, cfg.mode))
        directed = made_for("directed-adversary", directed_adversary_path(env, cfg.mode))
        surrogate = made_for("surrogate", surrogate_path(env, cfg.mode))
        if TRANSFER_ROW in rows_of:
            surrogate = ready_surrogate(cfg.policy, env, cfg.mode, eps, surrogate, cfg.horizon, log)
        if {"aril_a", SEARCH_ROW} & set(rows_of):
            wanted.append(AdversaryConfig(env=env, mode=cfg.mode, eps=eps, victim=cfg.policy, expert=cfg.expert,
                                          steps=cfg.adversary_steps, out=str(adversary)))
        if DIRECTED_ROW in rows_of:
            wanted.append(AdversaryConfig(env=env, mode=cfg.mode, eps=eps, victim=cfg.policy, expert=cfg.expert,
                                          policy="directed", steps=cfg.adversary_steps, out=str(directed)))
        files[env] = {"aril_a": adversary, SEARCH_ROW: adversary, DIRECTED_ROW: directed, TRANSFER_ROW: surrogate}
        for row in rows_of:
            attack = row_attack(row)
            jobs.append(asdict(EvalConfig(env=env, policy=cfg.policy, expert=cfg.expert,
                                          mode="clean" if attack == "none" else cfg.mode, attack=attack,
                                          eps=0.0 if attack == "none" else eps, k=_iterations(row, cfg.k),
                                          attack_file=str(files[env][row]) if row in files[env] else "",
                                          search=cfg.search if row == SEARCH_ROW else 0,
                                          episodes=cfg.episodes, seed=cfg.seed, horizon=cfg.horizon)))
    with session(cfg.workers, cfg.address):  # one Ray for the trainings and the evaluations
        ready_adversaries(wanted, cfg.retrain, log, cfg.workers, cfg.address)  # every env's at once, as tasks
        results = iter(evaluate_all(jobs, cfg.workers, cfg.address, log))
    fresh = []
    for env in files:
        cells = dict(earlier.get(env, {}))
        for row in rows_of:
            attack = row_attack(row)
            result = next(results)
            cell = _cell(result)
            clean = cells["none"]["mean"] if attack != "none" else cell["mean"]
            cells[row] = {**cell, "episodes": cfg.episodes, "eps": result["eps"],
                          "seeds": f"{cfg.seed}..{cfg.seed + cfg.episodes - 1}",
                          "mean_expert_loss": result["mean_expert_loss"],
                          "drop": round(1.0 - cell["mean"] / clean, 4) if clean else 0.0, **made}
            if "queries_per_step" in result:
                cells[row]["queries_per_step"] = result["queries_per_step"]
            if attack == "aril_a":
                cells[row]["adversary"] = load_adversary(files[env][row]).meta["provenance"]
            if attack == TRANSFER_ROW:
                cells[row]["surrogate"] = {"file": portable(str(files[env][row])),
                                           **load_policy(files[env][row], env).meta.provenance}
            log(f"[attack-table {cfg.mode}] {env} {ROW_NAMES[row]}: {cell['mean']:.1f} ± {cell['std']:.1f}",
                flush=True)
        fresh.append({"env": env, "cells": {row: cells[row] for row in ATTACK_ROWS if row in cells}})
    rows = _merge(json_path, lambda r: (r["env"],), fresh,
                  lambda old: (old.get("mode"), old.get("victim")) == (cfg.mode, cfg.policy))
    envs = [r["env"] for r in rows]
    cells = {r["env"]: r["cells"] for r in rows}
    shown = [a for a in ATTACK_ROWS if all(a in cells[e] for e in envs)]
    payload = {"mode": cfg.mode, "victim": cfg.policy, "rows": rows,
               "overall_drop": {a: round(sum(cells[e][a]["drop"] for e in envs) / len(envs), 4) for a in shown}}
    _write(json_path, payload, md_path, attack_markdown(payload))
    return payload


def table_rows(cfg: AttackTableConfig) -> list[str]:
    """The rows this run evaluates: ``rows:=``'s, else every one (ARIL-A + search where ``search`` > 0)."""
    if cfg.rows:
        return [check_name("row", r, ATTACK_ROWS) for r in comma_list(cfg.rows)]
    return [r for r in ATTACK_ROWS if cfg.search or r != SEARCH_ROW]


def _iterations(row: str, k: int) -> int:
    """``k:=`` for the row's attack; FGSM by finite differences at FGSM^k's iterations (its own default is one)."""
    return (k or FGSMk.STEPS) if row == FD_ROW else k


def _earlier_cells(json_path: Path, cfg: AttackTableConfig, rows: list[str]) -> dict:
    """Per env, the cells of an earlier run in ``json_path`` (same mode and victim), which this run keeps where it
    does not run their ``rows`` again: every one made with the same :data:`KEPT_SETTINGS` on this CPU model (the
    same files give other episodes on another); a cell made with others, or elsewhere, is an error naming which."""
    old = json.loads(json_path.read_text()) if json_path.exists() else {}
    if (old.get("mode"), old.get("victim")) != (cfg.mode, cfg.policy):
        return {}
    kept, here = {}, cpu()
    for row in old["rows"]:
        for name, cell in row["cells"].items():
            kept.setdefault(row["env"], {})[name] = cell
            if name in rows:  # run again: its settings and machine are this run's
                continue
            differ = [s for s in KEPT_SETTINGS if cell["settings"].get(s) != getattr(cfg, s)]
            if differ:
                raise ValueError(f"rows:={cfg.rows}: {json_path}'s {row['env']} {name} row was run with "
                                 + ", ".join(f"{s}:={cell['settings'].get(s)}" for s in differ) + " (this run: "
                                 + ", ".join(f"{s}:={getattr(cfg, s)}" for s in differ)
                                 + "); run it again too (add it to rows:=) or leave rows:= unset")
            elsewhere = cell.get("versions", {}).get("cpu")
            if elsewhere != here:
                raise ValueError(f"rows:={cfg.rows}: {json_path}'s {row['env']} {name} row was run on {elsewhere} "
                                 f"(this machine: {here}), whose episodes differ from the same files; run the table "
                                 "on one machine: leave rows:= unset")
    return kept


def attack_markdown(payload: dict) -> str:
    """The Adversary rows: mean ± std per env and the drop from clean, the overall drop per attack (the
    rows every env has), and the queries per step of the attacks that query the victim."""
    envs = [r["env"] for r in payload["rows"]]
    cells = {r["env"]: r["cells"] for r in payload["rows"]}
    table = "Table 1" if payload["mode"] == "sensory" else "Table 2"
    lines = [f"# {table} ({payload['mode']} attacks), Adversary rows — victim: {payload['victim']}", "",
             "Return, mean ± std over deterministic episodes, and the drop from clean; FGSM and FGSM^k are "
             "white-box (the victim's gradients), the others black-box: SPSA^k and ARIL-A + search query the "
             "victim's actions (queries per step in the last column), ARIL-A maps the state to a perturbation, "
             "ARIL-A, directed, to a direction in the victim's action space, which finite differences of the victim's "
             "answers turn into a perturbation (PA-AD's director and actor), FGSM^k "
             "on a surrogate attacks a copy fitted to the victim's answers (its questions and fidelity in the JSON). "
             "Each cell's episodes, seeds, adversary and command are in the JSON.", "",
             "| attack | " + " | ".join(f"{e} (eps {_table_eps(cells[e])})" for e in envs)
             + " | overall | queries/step |",
             "|---|" + "---|" * len(envs) + "---|---|"]
    for attack in payload["overall_drop"]:
        row = [f"{cells[e][attack]['mean']:.0f} ± {cells[e][attack]['std']:.0f}"
               + ("" if attack == "none" else f" ({-100 * cells[e][attack]['drop']:+.1f}%)") for e in envs]
        overall = "0%" if attack == "none" else f"{-100 * payload['overall_drop'][attack]:+.1f}%"
        queries = sorted({cells[e][attack].get("queries_per_step", 0) for e in envs})
        lines.append(f"| {ROW_NAMES[attack]} | " + " | ".join(row) + f" | {overall} | "
                     + ("–" if queries == [0] else " / ".join(f"{q:g}" for q in queries)) + " |")
    return "\n".join(lines) + "\n"


def _table_eps(cells: dict) -> str:
    """An env's eps in the table's head: its attacked cells' (every row but clean; a table of some rows alone, made
    with ``rows:=``, may lack any one of them)."""
    return next((f"{cell['eps']:g}" for row, cell in cells.items() if row != "none"), "–")


@dataclass
class DefenseTableConfig:
    """Arguments of ``aril defense-table``."""

    mode: str = arg("sensory", "sensory (Table 1) or physical (Table 2)")
    envs: str = arg(",".join(PAPER_ENVS), "comma-separated env ids")
    defenses: str = arg(",".join(DEFENSES), "comma-separated bundled learners (aril and dr: the ones of mode:=)")
    expert: str = arg("expert", "the expert")
    calibration: str = arg("", "where the eps per env and mode come from (unset: the bundled calibration, then the user's)")
    episodes: int = arg(20, "deterministic episodes per cell", low=1, high=100_000)
    seed: int = arg(seeds.DEFENSE_TABLE, "env seed of the first episode (and of the attack noise)",
                    low=0, high=2**31 - 1)
    k: int = arg(0, "iterations of FGSM^k and of FGSM^k by finite differences (0: 10), and of SPSA^k (0: 5)",
                 low=0, high=1000)
    adversary_steps: int = arg(1_000_000, "steps of the ARIL-A trained against each defense", low=1, high=10**9)
    adversary_seeds: int = arg(1, "ARIL-As trained against each defense, with training seeds 0, 1, ...: the cell's "
                                  "ARIL-A is the strongest of them (one adversary's seed can decide more than its "
                                  "training, results/aril_a_tuning.md)", low=1, high=10)
    adversary_dir: str = arg("", "where the adversaries against each defense go (default: the bundled ones, "
                                 "aril_ros/data/defense-adversary/; seed k > 0's name ends in -seed<k>); reused when "
                                 "they exist with the same eps")
    retrain: bool = arg(False, "train the adversaries even if they exist")
    horizon: int = arg(HORIZON, "steps per episode", low=1, high=1_000_000)
    workers: int = arg(2, "CPUs of the local Ray its evaluations run on as tasks (1: one after the other in this process)",
                       low=1, high=1024)
    address: str = arg("", "run the evaluations on this Ray cluster instead (<head ip>:6379, or auto)")
    out: str = arg("", "output path without suffix (default: results/defenses_<mode>)")


def defense_table(cfg: DefenseTableConfig, log=print) -> dict:
    """Each defense's return under the strongest of random, FGSM, FGSM^k, SPSA^k and an ARIL-A trained
    against that very defense; drops are from the clean DAgger learner's return (the paper's reference)."""
    made = stamp("aril defense-table", cfg)
    json_path, md_path = _outputs(cfg.out, f"results/defenses_{cfg.mode}")
    defenses = comma_list(cfg.defenses)
    unknown = [d for d in defenses if d not in DEFENSES]
    if unknown:
        raise ValueError(f"unknown defenses {unknown}; choose from {', '.join(DEFENSES)}")
    # first the adversaries (each trained against its defense if missing, all at once), then every evaluation
    settings, jobs, wanted = {}, {}, []
    for env in comma_list(cfg.envs):
        eps = calibrated_eps(env, cfg.mode, cfg.calibration or None)
        common = dict(env=env, expert=cfg.expert, episodes=cfg.episodes, seed=cfg.seed, horizon=cfg.horizon, k=cfg.k)
        reference = str(bundled_file(DEFAULT_POLICY, env))
        # the DAgger learner's clean return is the reference and maybe a row too: one job per policy
        jobs[env, reference, "none"] = EvalConfig(policy=reference, mode="clean", **common)
        for defense in defenses:
            policy = str(bundled_file(defense, env, cfg.mode))
            first = (Path(cfg.adversary_dir) / f"{env}-{cfg.mode}-{defense}.pt" if cfg.adversary_dir
                     else adversary_path(env, cfg.mode, defense))
            adversaries = [first if seed == 0 else first.with_name(f"{first.stem}-seed{seed}.pt")
                           for seed in range(cfg.adversary_seeds)]
            # the victim by its bundled name: a task on another node finds its own copy, and the file records the name
            wanted += [AdversaryConfig(env=env, mode=cfg.mode, eps=eps, victim=defense, expert=cfg.expert,
                                       steps=cfg.adversary_steps, seed=seed, out=str(adversary))
                       for seed, adversary in enumerate(adversaries)]
            settings[env, defense] = (eps, policy, adversaries)
            jobs[env, policy, "none"] = EvalConfig(policy=policy, mode="clean", **common)
            for threat in THREATS:
                if threat != "aril_a":
                    jobs[env, policy, threat] = EvalConfig(policy=policy, mode=cfg.mode, attack=threat, eps=eps,
                                                           **common)
            for adversary in adversaries:
                jobs[env, policy, str(adversary)] = EvalConfig(policy=policy, mode=cfg.mode, attack="aril_a",
                                                               eps=eps, attack_file=str(adversary), **common)
    with session(cfg.workers, cfg.address):  # one Ray for the trainings and the evaluations
        ready_adversaries(wanted, cfg.retrain, log, cfg.workers, cfg.address)
        cell = dict(zip(jobs, map(_cell, evaluate_all([asdict(j) for j in jobs.values()], cfg.workers,
                                                      cfg.address, log))))
    fresh = []
    for env in comma_list(cfg.envs):
        reference = cell[env, str(bundled_file(DEFAULT_POLICY, env)), "none"]["mean"]
        cells = {}
        for defense in defenses:
            eps, policy, adversaries = settings[env, defense]
            per_seed = [cell[env, policy, str(adversary)] for adversary in adversaries]
            strongest = min(range(len(adversaries)), key=lambda seed: per_seed[seed]["mean"])  # seed 0 wins a tie
            attacked = {threat: per_seed[strongest] if threat == "aril_a" else cell[env, policy, threat]
                        for threat in THREATS}
            worst = worst_attack(attacked)
            clean = cell[env, policy, "none"]
            cells[defense] = {
                "clean": clean["mean"], "clean_std": clean["std"], "attacks": attacked,
                "worst": worst, **attacked[worst],
                "drop": round(1.0 - attacked[worst]["mean"] / reference, 4) if reference else 0.0,
                "episodes": cfg.episodes, "eps": eps, "seeds": f"{cfg.seed}..{cfg.seed + cfg.episodes - 1}",
                "policy": portable(policy), "adversary": load_adversary(adversaries[strongest]).meta["provenance"],
                **({"aril_a_seeds": [c["mean"] for c in per_seed]} if len(adversaries) > 1 else {}), **made}
            log(f"[defense-table {cfg.mode}] {env} {DEFENSES[defense]}: clean {cells[defense]['clean']:.1f}, worst "
                f"{ATTACKS[worst]} {cells[defense]['mean']:.1f} ± {cells[defense]['std']:.1f}", flush=True)
        fresh.append({"env": env, "dagger_clean": reference, "cells": cells})
    old = json.loads(json_path.read_text()) if json_path.exists() else {}
    if old.get("mode") == cfg.mode:  # defenses not rerun keep their cells
        for row in fresh:
            kept = next((r["cells"] for r in old["rows"] if r["env"] == row["env"]), {})
            row["cells"] = {d: row["cells"].get(d, kept.get(d)) for d in DEFENSES if d in row["cells"] or d in kept}
    rows = _merge(json_path, lambda r: (r["env"],), fresh, lambda old: old.get("mode") == cfg.mode)
    envs = [r["env"] for r in rows]
    by_env = {r["env"]: r for r in rows}
    shown = [d for d in DEFENSES if all(d in by_env[e]["cells"] for e in envs)]
    payload = {"mode": cfg.mode, "rows": rows,
               "overall_drop": {d: round(sum(by_env[e]["cells"][d]["drop"] for e in envs) / len(envs), 4)
                                for d in shown}}
    _write(json_path, payload, md_path, defense_markdown(payload))
    return payload


def _seeds_text(payload: dict) -> str:
    """How many ARIL-As each cell took the strongest of, where more than one."""
    counts = sorted({len(c.get("aril_a_seeds", [0])) for r in payload["rows"] for c in r["cells"].values()})
    if counts == [1]:
        return ""
    return f" (the strongest of {' or '.join(map(str, counts))}, trained with seeds 0, 1, ...)"


def defense_markdown(payload: dict) -> str:
    """The Robust IL rows: each defense's worst-attack mean ± std per env (drop, attack), its overall drop."""
    envs = [r["env"] for r in payload["rows"]]
    by_env = {r["env"]: r for r in payload["rows"]}
    shown = list(payload["overall_drop"])
    table = "Table 1" if payload["mode"] == "sensory" else "Table 2"
    lines = [f"# {table} ({payload['mode']} attacks), Robust IL rows", "",
             "Each defense's return under the strongest of random, FGSM, FGSM^k, SPSA^k and an ARIL-A trained against "
             f"that defense{_seeds_text(payload)} (in brackets), mean ± std over deterministic episodes; the drop is "
             "from the clean DAgger learner. Each cell's seeds, clean return, every attack's figure and the command "
             "are in the JSON.", "",
             "| defense | " + " | ".join(f"{e} (eps {by_env[e]['cells'][shown[0]]['eps']:g})" for e in envs)
             + " | overall |", "|---|" + "---|" * len(envs) + "---|",
             "| DAgger, clean | " + " | ".join(f"{by_env[e]['dagger_clean']:.0f}" for e in envs) + " | 0% |"]
    for d in shown:
        row = [f"{c['mean']:.0f} ± {c['std']:.0f} ({-100 * c['drop']:+.1f}%, {ATTACKS[c['worst']]})"
               for c in (by_env[e]["cells"][d] for e in envs)]
        lines.append(f"| {DEFENSES[d]} | " + " | ".join(row) + f" | {-100 * payload['overall_drop'][d]:+.1f}% |")
    return "\n".join(lines) + "\n"
