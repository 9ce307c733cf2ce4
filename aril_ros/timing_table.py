"""``aril timing-table``: each defense under its worst timing attack (issue 39), in the report's layout.

Per env, defense and training seed (seed 0: the bundled learner; seed k: the 3-seed protocol's, ``seed_dir``), the
policy is run clean but for one timing attack (:mod:`aril_ros.timing`) per cell: every observation up to ``k`` steps
late, every action up to ``k`` steps late, or up to ``k/10`` of the observations dropped, for ``k`` in ``steps``;
each picked by ``fixed`` (the most every step), ``random`` (per step) and, at the budgets ``learned`` names, a timing
adversary trained against that very policy (:mod:`aril_ros.timing_adversary`, ``learned_steps`` PPO steps). A
budget's cell is the worst chooser's (the lowest mean return over the seeds), with its mean over the training seeds and
a 95% interval over them (:func:`aril_ros.report.stats.summarise`); the table writes, per env, one row per defense:
clean, then every budget. Beside it, per budget with a learned chooser, the three choosers side by side: what
learning *when* to be late buys over random latency of the same budget.

Every cell is kept in ``<out>.json`` with its per-episode returns and settings, the CPU it ran on among them, written
as each cell finishes; a rerun keeps the cells it finds with the same settings (a run stopped, or a fresh clone on the
same CPU model, resumes: commit ``<out>.json`` and the adversaries as they come; on another CPU model every cell runs again, since the same
files give other episodes there, and the trained adversaries are kept). The timing adversaries go to ``adversary_dir``, one per (env,
defense, seed, budget), reused when trained for the same budget against the same policy file. A ``label=path`` row
with no file on an env (a defense trained on some envs only) is left out of that env's table, which says so.

Below each env's tables, a paragraph computed from them: which defense keeps the most under its worst timing attack
(and in how many columns the intervals over seeds separate it from the next), and what the learned chooser takes
beside random latency of the same budget.
"""
from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

from . import seeds
from .adversary import AdversaryConfig, ready_adversaries
from .args import arg, comma_list
from .envs import HORIZON
from .evaluation import EvalConfig, evaluate_each
from .files import write_atomically
from .provenance import cpu, portable, stamp
from .registry import DEFENSES, PAPER_ENVS, PER_MODE_POLICIES, bundled_file
from .report.plots import plot_budget_sweeps
from .report.stats import summarise
from .sweep import digest_of, session
from .timing import CHOOSERS, TimingBudget

KINDS = {"delay": "observations late", "action_delay": "actions late", "drop": "observations dropped"}
"""The timing attacks a table sweeps, each alone, and how its columns name them."""


@dataclass
class TimingTableConfig:
    """Arguments of ``aril timing-table``."""

    envs: str = arg(",".join(PAPER_ENVS), "comma-separated env ids")
    defenses: str = arg("dagger,dart,dr,aril", "comma-separated rows: bundled learners (dr and aril: those of "
                                               "mode:=), or label=path with {env} and {seed} in the path (a "
                                               "defense trained elsewhere, e.g. with a timing budget in its loop)")
    mode: str = arg("sensory", "whose bundled dr and aril (trained against sensory or physical attacks)")
    training_seeds: str = arg("0,1,2", "training seeds per defense: 0 the bundled file, k > 0 seed_dir's")
    seed_dir: str = arg("results/report-full/policies", "where the 3-seed protocol keeps seeds k > 0 "
                                                        "(<defense>-<env>[-<mode>]-seed<k>.pt)")
    kinds: str = arg(",".join(KINDS), f"comma-separated timing attacks, each alone ({', '.join(KINDS)})")
    steps: str = arg("1,2,3", "comma-separated budgets k: delay and action_delay k steps, drop k/10")
    learned: str = arg("delay2,action_delay2,drop2", "the budgets (kind and k) where a timing adversary is trained "
                                                     "against each policy; empty: fixed and random only")
    learned_steps: int = arg(500_000, "PPO steps of each timing adversary", low=1, high=10**9)
    expert: str = arg("expert", "the expert")
    episodes: int = arg(20, "deterministic episodes per cell", low=1, high=100_000)
    seed: int = arg(seeds.DEFENSE_TABLE, "env seed of the first episode (and of the timing draws)", low=0,
                    high=2**31 - 1)
    horizon: int = arg(HORIZON, "steps per episode", low=1, high=1_000_000)
    adversary_dir: str = arg("results/timing-adversaries", "where the timing adversaries go (committed with the table: a "
                                                            "fresh clone resumes from them)")
    workers: int = arg(2, "CPUs of the local Ray its trainings and evaluations run on (1: in this process)",
                       low=1, high=1024)
    address: str = arg("", "run them on this Ray cluster instead (<head ip>:6379, or auto)")
    out: str = arg("results/timing", "output path without suffix (.json and .md are written)")


@dataclass(frozen=True)
class Budget:
    """One timing attack of the table: its kind and ``k``."""

    kind: str
    k: int

    @property
    def name(self) -> str:
        return f"{self.kind}{self.k}"

    @property
    def timing(self) -> TimingBudget:
        return TimingBudget(**{self.kind: self.k / 10 if self.kind == "drop" else self.k})

    @property
    def label(self) -> str:
        return f"{self.k / 10:g}" if self.kind == "drop" else f"{self.k}"


def budgets(cfg: TimingTableConfig) -> list[Budget]:
    kinds = comma_list(cfg.kinds)
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        raise ValueError(f"unknown timing attacks {unknown}; choose from {', '.join(KINDS)}")
    steps = [int(k) for k in comma_list(cfg.steps)]
    if any(not 1 <= k <= 9 for k in steps):
        raise ValueError(f"steps:= are budgets 1..9 (drop k/10), got {cfg.steps}")
    return [Budget(kind, k) for kind in kinds for k in steps]


def learned_budgets(cfg: TimingTableConfig, swept: list[Budget]) -> list[Budget]:
    names = {b.name: b for b in swept}
    missing = [n for n in comma_list(cfg.learned) if n not in names]
    if missing:
        raise ValueError(f"learned:= names budgets the table does not sweep: {missing} (swept: {', '.join(names)})")
    return [names[n] for n in comma_list(cfg.learned)]


def defense_files(cfg: TimingTableConfig, env: str) -> dict[str, list[Path]]:
    """Each row's policy file per training seed; a ``label=path`` row none of whose files exists on ``env`` is not
    among them (trained on other envs only), one with some of them missing is an error."""
    rows = {}
    for entry in comma_list(cfg.defenses):
        label, _, pattern = entry.partition("=")
        if pattern:
            files = [Path(pattern.format(env=env, seed=s)) for s in map(int, comma_list(cfg.training_seeds))]
            if any(file.is_file() for file in files):
                rows[label] = files
            continue
        if label not in DEFENSES:
            raise ValueError(f"unknown defense {label!r}: a bundled learner ({', '.join(DEFENSES)}) or label=path")
        mode = cfg.mode if label in PER_MODE_POLICIES else None
        rows[label] = [bundled_file(label, env, mode) if s == 0 else
                       Path(cfg.seed_dir) / f"{label}-{env}{f'-{mode}' if mode else ''}-seed{s}.pt"
                       for s in map(int, comma_list(cfg.training_seeds))]
    for label, files in rows.items():
        for file in files:
            if not file.is_file():
                raise ValueError(f"{label} on {env}: no policy file {file} (train the seed, or leave it out of "
                                 "training_seeds:=)")
    return rows


def timing_table(cfg: TimingTableConfig, log=print) -> dict:
    """Every cell the table needs and has not kept, then the table (see the module docstring)."""
    made = stamp("aril timing-table", cfg)
    json_path, md_path = Path(cfg.out).with_suffix(".json"), Path(cfg.out).with_suffix(".md")
    swept = budgets(cfg)
    learned = learned_budgets(cfg, swept)
    cells = json.loads(json_path.read_text())["cells"] if json_path.exists() else {}
    common = dict(expert=cfg.expert, episodes=cfg.episodes, seed=cfg.seed, horizon=cfg.horizon, mode="clean")
    jobs, wanted = {}, []
    for env in comma_list(cfg.envs):
        for label, files in defense_files(cfg, env).items():
            for s, file in zip(map(int, comma_list(cfg.training_seeds)), files):
                digest = digest_of(file.read_bytes())
                evaluations = {"clean": EvalConfig(env=env, policy=str(file), **common)}
                for budget in swept:
                    for chooser in ("fixed", "random", *(("learned",) if budget in learned else ())):
                        adversary = (Path(cfg.adversary_dir) / f"{env}-{label}-seed{s}-{budget.name}.pt"
                                     if chooser == "learned" else None)
                        if adversary is not None:
                            wanted.append(AdversaryConfig(env=env, mode="clean", **asdict(budget.timing),
                                                          victim=portable(str(file)), expert=cfg.expert,
                                                          steps=cfg.learned_steps, out=str(adversary)))
                        evaluations[f"{budget.name}-{chooser}"] = EvalConfig(
                            env=env, policy=str(file), **common, **asdict(budget.timing), timing=chooser,
                            timing_file=str(adversary or ""))
                for name, job in evaluations.items():
                    key = f"{env}|{label}|{s}|{name}"
                    # the CPU too: torch's kernels differ between CPU models, and so do the episodes of one file
                    settings = {"policy_sha256": digest, "episodes": cfg.episodes, "seed": cfg.seed,
                                "horizon": cfg.horizon, "cpu": cpu(),
                                **({"learned_steps": cfg.learned_steps} if name.endswith("learned") else {})}
                    if cells.get(key, {}).get("settings") != settings:
                        jobs[key] = (job, settings)
    log(f"[timing-table] {len(jobs)} cells to run ({len(cells)} kept), {len(wanted)} timing adversaries wanted",
        flush=True)

    def write() -> dict:
        payload = {"cells": dict(sorted(cells.items())), **made, "table": table(cfg, cells, swept, learned)}
        json_path.parent.mkdir(parents=True, exist_ok=True)
        # in one step: a run killed while writing keeps the cells it had, not half a file
        write_atomically(json_path, lambda partial: partial.write_text(json.dumps(payload, indent=1) + "\n"))
        return payload

    with session(cfg.workers, cfg.address):
        ready_adversaries(wanted, False, log, cfg.workers, cfg.address)
        keys = list(jobs)
        for index, result in evaluate_each([asdict(jobs[key][0]) for key in keys], cfg.workers, cfg.address, log,
                                           label="timing-table cells"):
            job, settings = jobs[keys[index]]
            cells[keys[index]] = {"returns": result["returns"], "mean_return": result["mean_return"],
                                  "settings": settings, "policy": portable(job.policy),
                                  **({"timing_file": portable(job.timing_file)} if job.timing_file else {})}
            write()  # as each cell finishes: a run stopped resumes from it
    payload = write()
    for env in comma_list(cfg.envs):
        plot_sweeps(cfg, payload["table"], env, swept, learned)
    md_path.write_text(markdown(cfg, payload["table"], swept, learned))
    return payload


def figure_path(cfg: TimingTableConfig, env: str) -> Path:
    """Where the table's sweep figure of ``env`` goes: beside ``<out>.md``."""
    return Path(f"{cfg.out}-{env}.png")


def plot_sweeps(cfg: TimingTableConfig, rows: dict, env: str, swept: list[Budget], learned: list[Budget]) -> None:
    """Return against the budget, one panel per timing attack: each defense's worst cell (mean, 95% interval over the
    seeds), from its clean return at budget 0; a panel's title names the budgets with a learned chooser."""
    kinds_swept = list(dict.fromkeys(b.kind for b in swept))
    series = {}
    for key, row in rows.items():
        if not key.startswith(f"{env}|") or not row["clean"]:
            continue
        kinds = {}
        for kind in kinds_swept:
            points = [(0.0, row["clean"]["mean"], row["clean"]["ci95"])]
            for budget in (b for b in swept if b.kind == kind):
                entry = row["budgets"][budget.name]
                if entry["worst"]:
                    cell = entry["choosers"][entry["worst"]]
                    points.append((float(budget.label), cell["mean"], cell["ci95"]))
            kinds[kind] = points
        label = key.split("|")[1]
        series[DEFENSES.get(label, label)] = kinds
    if series:
        panels = {}
        for kind in kinds_swept:
            at = [b.label for b in learned if b.kind == kind]
            panels[kind] = KINDS[kind] + (f" (learned at {', '.join(at)})" if at else "")
        plot_budget_sweeps(series, panels,
                           f"{env}: return under each timing attack's worst chooser (mean, 95% interval over seeds)",
                           figure_path(cfg, env))


def table(cfg: TimingTableConfig, cells: dict, swept: list[Budget], learned: list[Budget]) -> dict:
    """Per env and defense: clean, and per budget every chooser's cell and the worst's (over the training seeds)."""
    seed_list = list(map(int, comma_list(cfg.training_seeds)))
    out = {}
    for env in comma_list(cfg.envs):
        for label in [entry.partition("=")[0] for entry in comma_list(cfg.defenses)]:
            def over_seeds(name: str) -> dict | None:
                per_seed = [cells.get(f"{env}|{label}|{s}|{name}", {}).get("returns") for s in seed_list]
                return None if None in per_seed else {k: round(v, 3) if isinstance(v, float) else v
                                                      for k, v in summarise(per_seed).items()}
            row = {"clean": over_seeds("clean"), "budgets": {}}
            for budget in swept:
                choosers = {c: over_seeds(f"{budget.name}-{c}") for c in CHOOSERS
                            if c != "learned" or budget in learned}
                present = {c: v for c, v in choosers.items() if v}
                worst = min(present, key=lambda c: present[c]["mean"]) if present else None
                row["budgets"][budget.name] = {"choosers": choosers, "worst": worst}
            if row["clean"] or any(entry["worst"] for entry in row["budgets"].values()):
                out[f"{env}|{label}"] = row  # a row with no cell on this env: trained on other envs only
    return out


def markdown(cfg: TimingTableConfig, rows: dict, swept: list[Budget], learned: list[Budget]) -> str:
    md = Path(cfg.out).with_suffix(".md")
    return "\n".join(["# Timing attacks: each defense under its worst timing attack", "",
                      *sections(cfg, rows, swept, learned, "##", md)])


def report_lines(path: Path, report: Path) -> list[str]:
    """The timing section of the report at ``report`` from a kept table (``<out>.json`` of ``aril timing-table``),
    headed at level 3; nothing when there is none."""
    if not path.is_file():
        return []
    payload = json.loads(path.read_text())
    cfg = TimingTableConfig(**payload["settings"])
    swept = budgets(cfg)
    learned = learned_budgets(cfg, swept)
    link = os.path.relpath(path, report.parent)
    return [f"Made by `{payload['command']}` (on {payload['versions']['cpu']}; [`{path}`]({link}) keeps every "
            "cell).", "", *sections(cfg, table(cfg, payload["cells"], swept, learned), swept, learned, "###", report)]


def sections(cfg: TimingTableConfig, rows: dict, swept: list[Budget], learned: list[Budget], heading: str,
             page: Path) -> list[str]:
    """The table's explanation, then per env its table, its sweep figure (linked from ``page``), the learned
    chooser's table beside it and what they show."""
    seed_list = comma_list(cfg.training_seeds)
    lines = [f"Return under each timing attack alone (the policy clean otherwise), the worst of fixed, random"
             f"{' and a learned timing adversary (*: at this budget)' if learned else ''} (its initial in brackets: "
             f"f, r, l), mean over training seeds {', '.join(seed_list)} ± a 95% interval over them, "
             f"{cfg.episodes} episodes each from env seed {cfg.seed}. Columns: the budget k of each attack (delay "
             "and action delay in steps, drop as a share of the steps). Every cell, per seed and per episode, with "
             "its command and CPU, is in the JSON.", ""]
    for env in comma_list(cfg.envs):
        lines += [f"{heading} {env}", "", "| defense | clean | " + " | ".join(
            f"{KINDS[b.kind]} {b.label}{'*' if b in learned else ''}" for b in swept) + " |",
                  "|---|---|" + "---|" * len(swept)]
        for key, row in rows.items():
            if not key.startswith(f"{env}|"):
                continue
            label = key.split("|")[1]
            shown = [_cell(row["clean"])]
            for budget in swept:
                entry = row["budgets"][budget.name]
                worst = entry["choosers"].get(entry["worst"]) if entry["worst"] else None
                shown.append(_cell(worst) + (f" ({entry['worst'][0]})" if worst else ""))
            lines.append(f"| {DEFENSES.get(label, label)} | " + " | ".join(shown) + " |")
        lines.append("")
        if learned:
            lines += [f"Learned vs random vs fixed on {env}, same budget (mean return over the seeds):", "",
                      "| defense | " + " | ".join(f"{KINDS[b.kind]} {b.label}: fixed / random / learned"
                                                   for b in learned) + " |", "|---|" + "---|" * len(learned)]
            for key, row in rows.items():
                if key.startswith(f"{env}|"):
                    label = key.split("|")[1]
                    lines.append(f"| {DEFENSES.get(label, label)} | " + " | ".join(
                        " / ".join(_mean(row["budgets"][b.name]["choosers"].get(c)) for c in CHOOSERS)
                        for b in learned) + " |")
            lines.append("")
        figure = figure_path(cfg, env)
        if figure.is_file():
            lines += [f"![{env}: return vs timing budget]({os.path.relpath(figure, page.parent)})", ""]
        shown = {key.split("|")[1]: row for key, row in rows.items() if key.startswith(f"{env}|")}
        absent = [entry.partition("=")[0] for entry in comma_list(cfg.defenses)
                  if entry.partition("=")[0] not in shown]
        if absent:
            lines += [f"Not on {env} (no policy file of it there): {', '.join(absent)}.", ""]
        lines += [findings(shown, swept, learned), ""]
    return lines


def findings(rows: dict, swept: list[Budget], learned: list[Budget]) -> str:
    """What one env's table shows, in words computed from it: the defense that keeps the most under its worst timing
    attack, in how many columns (and in how many its interval over the seeds clears the next one's), what it keeps
    clean; and at each learned budget, the share of clean return each chooser leaves, averaged over the defenses."""
    def worst(row: dict, budget: Budget) -> dict | None:
        entry = row["budgets"][budget.name]
        return entry["choosers"].get(entry["worst"]) if entry["worst"] else None

    leads, clear, columns = {}, {}, 0
    for budget in swept:
        ranked = sorted(((cell, label) for label, row in rows.items() if (cell := worst(row, budget))),
                        key=lambda pair: -pair[0]["mean"])
        if len(ranked) < 2:
            continue
        columns += 1
        (top, label), (second, _) = ranked[:2]
        leads[label] = leads.get(label, 0) + 1
        clear[label] = clear.get(label, 0) + (top["mean"] - top["ci95"] > second["mean"] + second["ci95"])
    if not columns:
        return "Too few defenses with cells here to compare."
    order = sorted(leads, key=lambda label: -leads[label])
    name = lambda label: DEFENSES.get(label, label)  # noqa: E731
    cleans = {label: row["clean"]["mean"] for label, row in rows.items() if row["clean"]}
    best_clean = max(cleans, key=cleans.get) if cleans else None
    text = (f"Under its worst timing attack {name(order[0])} keeps the most return in {leads[order[0]]} of {columns} "
            f"columns (its interval over the seeds clear of the next defense's in "
            f"{clear[order[0]] or 'none of them'})"
            + "".join(f", {name(label)} in {leads[label]}" for label in order[1:]) + ".")
    if best_clean and order[0] in cleans:
        text += (f" Clean, {name(order[0])} keeps {cleans[order[0]]:.0f}" + (
            ", the most." if best_clean == order[0] else f" ({name(best_clean)}: {cleans[best_clean]:.0f})."))
    for budget in learned:
        shares = {chooser: [] for chooser in CHOOSERS}
        worst_count = 0
        for row in rows.values():
            entry = row["budgets"][budget.name]
            if not row["clean"] or not all(entry["choosers"].get(c) for c in CHOOSERS):
                continue
            worst_count += entry["worst"] == "learned"
            for chooser in CHOOSERS:
                shares[chooser].append(entry["choosers"][chooser]["mean"] / row["clean"]["mean"])
        if shares["learned"]:
            text += (f" With {KINDS[budget.kind]} {budget.label}, the learned timing adversary is the worst chooser "
                     f"against {worst_count} of {len(shares['learned'])} defenses and leaves "
                     f"{100 * sum(shares['learned']) / len(shares['learned']):.0f}% of clean return on average, "
                     f"random latency of the same budget {100 * sum(shares['random']) / len(shares['random']):.0f}%, "
                     f"fixed (the most every step) {100 * sum(shares['fixed']) / len(shares['fixed']):.0f}%.")
    return text


def _cell(cell: dict | None) -> str:
    if not cell:
        return "–"
    half = cell["ci95"]
    return f"{cell['mean']:.0f}" + (f" ± {half:.0f}" if half == half else "")


def _mean(cell: dict | None) -> str:
    return f"{cell['mean']:.0f}" if cell else "–"
