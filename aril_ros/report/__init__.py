"""``aril report``: ``docs/results.md`` regenerated from scratch, every figure traceable.

    aril report budget:=quick          # under ~30 min on 2 cores: the bundled policies and adversaries
    aril report budget:=full           # the paper's protocol: 3 training seeds, 50 episodes, wide sweeps

What it runs, in order (:func:`build_report`), and the room of this package that does it:

1. **Performance** (``perf``, first, on an idle machine): every benchmark registered in the
   ``aril_ros.benchmarks`` entry points (engine, graph, adversary) as ``python -m <module>``, their
   closing JSON lines read back; ratios to raw MuJoCo.
2. **Policies and adversaries** (``artifacts``) per defense, env, mode and training seed, and a surrogate of
   each DAgger policy (its transfer row's). Seed 0 is the bundled policy (``aril_ros/data/<defense>/``), the
   bundled ARIL-A trained against it (``registry.adversary_path``) and, for DAgger, the bundled surrogate
   (``registry.surrogate_path``); other seeds are trained here by the bundled policy's own settings (its
   provenance) with ``seed`` changed, then an ARIL-A against each, into ``<work_dir>/``, ``workers``
   trainings side by side (each on one thread; a finished file is kept, so an interrupted run resumes, and a
   learner's training keeps its finished rounds in ``<work_dir>/learners/<name>/`` until it finishes, so an
   interrupted ARIL resumes after its last round). A missing or failed one makes its cells say why.
3. **Evaluations** (``jobs``), ``workers`` at a time in spawned processes: every policy clean and under
   random, FGSM, FGSM^k, SPSA^k and its own ARIL-A at the calibrated eps (the tables), DAgger also under the
   black-box rows (``paper.BLACK_BOX_ROWS``: transfer from its surrogate, ARIL-A + search), and under the sweep attacks
   at multiples of it (the eps sweeps; ARIL-A's perturbation is scaled to each eps), episodes from
   ``seeds.DEFENSE_TABLE``. Each evaluation is cached in ``<work_dir>/cache/`` under a key of its
   arguments and the files' digests, so an interrupted report resumes and a changed policy is evaluated again.
4. **Report**: table cells (``stats``, the one producer of cells, shared with ``aril attack-table`` and
   ``defense-table``), tables in the paper's layout beside the paper's figures (``tables``, ``paper``),
   sweeps and ARIL's rounds as PNG (``plots``), optional GIFs of an attack (``render:=true``), the
   text and the comparison with the paper (``text``), and the compute the protocol took (``compute``: CPU-hours
   per stage from the times each evaluation and each file's training recorded, and the hours it would take on N
   cores).

Files written (all committed: the report is built from them)::

    docs/results.md                      the report
    docs/results/report.json             every evaluation (per-episode returns), file digests, benchmarks
    docs/results/sweep-<env>-<mode>.png  return vs eps per defense, one panel per attack
    docs/results/aril-rounds.png         ARIL's clean and attacked return per round
    docs/results/attack-<env>-<mode>.gif clean | attacked DAgger | attacked ARIL (render:=true)
"""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from ..args import arg, comma_list
from ..envs import HORIZON
from ..provenance import git_revision, portable, stamp
from ..registry import (
    ATTACKED_MODES,
    DEFAULT_ENV,
    PAPER_DEFENSES,
    PAPER_ENVS,
    THREATS,
    calibrated_eps,
)
from ..seeds import DEFENSE_TABLE
from ..sweep import session
from .artifacts import Artifacts, aril_rounds
from .compute import compute_summary
from .jobs import by_cell, digest, evaluated_on, evaluation_plan, evaluations_json, run_jobs, seed_means
from .perf import run_benchmarks
from .plots import plot_figures
from .tables import make_tables, table_cells, top_two
from .text import report_markdown

__all__ = ["ReportConfig", "build_report"]

BUDGETS = {
    "quick": dict(seeds="0", episodes=20, sweep_episodes=10, sweep_scales="0.5,2",
                  sweep_attacks=",".join(THREATS), bench_steps=10_000),
    "full": dict(seeds="0,1,2", episodes=50, sweep_episodes=20, sweep_scales="0.25,0.5,1.5,2,3",
                 sweep_attacks=",".join(THREATS), bench_steps=50_000),
}


@dataclass
class ReportConfig:
    """Arguments of ``aril report``; 0 or empty takes the budget's value."""

    budget: str = arg("quick", "quick (bundled policies, 1 seed, 20 episodes: under ~30 min on 2 cores) or full "
                               "(3 training seeds, 50 episodes, wide sweeps: the paper's protocol, many hours; "
                               "resumable)")
    envs: str = arg(",".join(PAPER_ENVS), "comma-separated env ids")
    modes: str = arg(",".join(ATTACKED_MODES), "comma-separated attack modes")
    seeds: str = arg("", "training seeds per defense (seed 0: the bundled policies; others are trained)")
    more_seeds: str = arg("", "training seeds added, for every defense, to each env and mode whose top two defenses "
                              "seeds:= cannot separate (the 95% interval of their difference over seeds holds 0): "
                              "compute spent where it separates")
    episodes: int = arg(0, f"deterministic evaluation episodes per table cell and seed (env seeds "
                           f"{DEFENSE_TABLE}...)", low=0, high=100_000)
    sweep_episodes: int = arg(0, "episodes per eps-sweep point and seed", low=0, high=100_000)
    sweep_scales: str = arg("", "eps sweep points as multiples of the calibrated eps (besides 0 and 1)")
    sweep_attacks: str = arg("", "attacks of the eps sweeps")
    adversary_steps: int = arg(1_000_000, "ARIL-A steps against each defense and seed that has no adversary yet",
                               low=1, high=10**9)
    horizon: int = arg(HORIZON, f"steps per episode (the paper's {HORIZON}; fewer only for a smoke test)",
                       low=1, high=1_000_000)
    workers: int = arg(2, "CPUs of the local Ray the trainings and evaluations run on as tasks, one CPU each (1: one "
                          "after the other in this process, without Ray)", low=1, high=1024)
    address: str = arg("", "run the tasks on this Ray cluster instead (<head ip>:6379, or auto for the one "
                           "this machine has joined; workers:= is then ignored)")
    perf: bool = arg(True, "run the benchmarks (the performance section)")
    bench_steps: int = arg(0, "steps per engine and adversary benchmark", low=0, high=10**9)
    render: bool = arg(False, "render GIFs of an attack (MuJoCo offscreen on the CPU) for render_envs")
    render_envs: str = arg(DEFAULT_ENV, "envs to render when render:=true (both modes each)")
    work_dir: str = arg("runs/report", "trained seeds, their adversaries and the evaluation cache")
    fresh: bool = arg(False, "ignore cached evaluations")
    evaluate: bool = arg(True, "evaluate and write the report; false: only make the files its evaluations need (each "
                               "defense's policies, the ARIL-As against them, DAgger's surrogates) and stop, for a "
                               "machine whose CPU model the cache does not serve (it would run every evaluation "
                               "again); name the cells with envs:=, modes:= and seeds:=")
    out: str = arg("docs/results.md", "the report; its figures and JSON go to <out without .md>/")


def resolved(cfg: ReportConfig) -> ReportConfig:
    """``cfg`` with the budget's values where it leaves them unset, checked."""
    if cfg.budget not in BUDGETS:
        raise ValueError(f"unknown budget {cfg.budget!r}; choose one of {', '.join(BUDGETS)}")
    cfg = dataclasses.replace(cfg, **{k: getattr(cfg, k) or v for k, v in BUDGETS[cfg.budget].items()})
    if cfg.workers < 1 or cfg.horizon < 1:
        raise ValueError("workers:= and horizon:= must be at least 1")
    if not cfg.evaluate and cfg.more_seeds:
        raise ValueError("more_seeds:= goes where the evaluations of seeds:= cannot separate a cell, so it needs "
                         "evaluate:=true; to only train, name the cells with envs:= and modes:= and every seed in "
                         "seeds:=")
    if any(s <= 0 or s == 1.0 for s in scales_of(cfg)):
        raise ValueError(f"sweep_scales:= takes multiples other than 0 and 1 (those are the tables'), "
                         f"got {scales_of(cfg)}")
    return cfg


def scales_of(cfg: ReportConfig) -> list[float]:
    return [float(s) for s in comma_list(cfg.sweep_scales)]


def _uncommitted() -> str:
    """A mark on the revision when tracked files differ from it: the figures may not be reproducible from it."""
    done = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=Path(__file__).resolve().parent,
                          capture_output=True, text=True)
    return " (with uncommitted changes)" if done.returncode == 0 and done.stdout.strip() else ""


def _relative(path: Path) -> str:
    return portable(str(Path(path).resolve()))


def report_stamp(cfg: ReportConfig) -> dict:
    """The report's provenance: command, settings, git revision (marked when the checkout differs), time, cores."""
    made = stamp("aril report", cfg)
    return {**made, "git_revision": git_revision() + _uncommitted(), "cores": os.cpu_count()}


def render_gifs(envs: list[str], modes: list[str], figures_dir: Path, log) -> list[Path]:
    from ..render import RenderConfig, render

    return [render(RenderConfig(env=env, mode=mode, width=240, height=180, steps=240, every=4,
                                out=str(figures_dir / f"attack-{env}-{mode}.gif")), log=log)
            for env in envs for mode in modes]


@dataclass
class Evaluated:
    """What a set of (defense, env, mode, seed) combos gave: their files, the evaluation plan and its per-episode
    returns, how many evaluations ran and were read from the cache, and how each distinct one ran."""

    policies: dict
    adversaries: dict
    surrogates: dict
    directed: dict
    plan: list
    returns: list
    counts: dict
    runs: list


def files_needed(store: Artifacts, combos: list[tuple], eps: dict, horizon: int) -> tuple[dict, dict, dict, dict]:
    """Each combo's policy (trained when not bundled), the ARIL-A against it, and DAgger's surrogate and directed
    ARIL-A."""
    policies = store.policies(combos)
    adversaries = store.adversaries(policies, eps)
    return (policies, adversaries, store.surrogates(policies, eps, horizon),
            store.adversaries(policies, eps, directed=True))


def evaluated(cfg: ReportConfig, store: Artifacts, combos: list[tuple], eps: dict, sweep_attacks: list[str],
              log) -> Evaluated:
    """The files each combo needs (:func:`files_needed`), then every evaluation of the plan, from the cache or run
    (:func:`.jobs.run_jobs`)."""
    policies, adversaries, surrogates, directed = files_needed(store, combos, eps, cfg.horizon)
    plan = evaluation_plan(policies, adversaries, surrogates, directed, eps, cfg.episodes, cfg.sweep_episodes,
                           sweep_attacks, scales_of(cfg), cfg.horizon)
    returns, counts, runs = run_jobs([job for _, job in plan], Path(cfg.work_dir) / "cache", cfg.workers,
                                     cfg.address, cfg.fresh, log)
    return Evaluated(policies, adversaries, surrogates, directed, plan, returns, counts, runs)


def leads(done: Evaluated, envs: list[str], modes: list[str]) -> dict[tuple, dict | None]:
    """Per (env, mode), its top two defenses and the first's lead over the second, seed by seed
    (:func:`.tables.top_two`)."""
    evals, means = by_cell(done.plan, done.returns), seed_means(done.plan, done.returns)
    return {(env, mode): top_two(table_cells(evals, env, mode), means.get((env, mode), {}))
            for env in envs for mode in modes}


def trained_only(cfg: ReportConfig, combos: list[tuple], eps: dict, log) -> None:
    """``evaluate:=false``: the files the evaluations of ``combos`` need, made where missing, and nothing evaluated;
    what could not be made is named."""
    with session(cfg.workers, cfg.address):
        store = Artifacts(cfg.work_dir, cfg.workers, cfg.address, cfg.adversary_steps, log)
        policies, adversaries, _, directed = files_needed(store, combos, eps, cfg.horizon)
    made = [p for p in (*policies.values(), *adversaries.values(), *directed.values()) if p]
    log(f"[report] evaluate:=false: {len(made)} policy and adversary files ready (seed 0's bundled, the others' in "
        f"{cfg.work_dir}/) for "
        f"{len(combos)} defense, env, mode and seed combinations; nothing evaluated, no report written"
        + "".join(f"\n  missing {' '.join(map(str, key))}: {why}" for key, why in store.missing.items()), flush=True)


def build_report(cfg: ReportConfig, log=print) -> Path | None:
    cfg, started = resolved(cfg), time.time()
    envs, modes, training_seeds = comma_list(cfg.envs), comma_list(cfg.modes), [int(s) for s in comma_list(cfg.seeds)]
    eps = {(env, mode): calibrated_eps(env, mode) for env in envs for mode in modes}
    combos = [(defense, env, mode, seed) for env in envs for mode in modes for defense in PAPER_DEFENSES
              for seed in training_seeds]
    if not cfg.evaluate:
        return trained_only(cfg, combos, eps, log)
    sweep_attacks = comma_list(cfg.sweep_attacks)
    out, figures_dir = Path(cfg.out), Path(cfg.out).with_suffix("")
    figures_dir.mkdir(parents=True, exist_ok=True)
    made = report_stamp(cfg)

    # 1. performance, first, on an idle machine
    benchmarks = run_benchmarks(cfg.bench_steps, log) if cfg.perf else {}

    # 2. each defense's policy and the ARIL-A against it, per env, mode and training seed; 3. the evaluations, from
    # the cache or run; all as tasks of one Ray. Then, with more_seeds, the same again on the cells whose top two
    # defenses the first seeds could not separate
    with session(cfg.workers, cfg.address):
        store = Artifacts(cfg.work_dir, cfg.workers, cfg.address, cfg.adversary_steps, log)
        done = evaluated(cfg, store, combos, eps, sweep_attacks, log)
        more = [int(s) for s in comma_list(cfg.more_seeds)]
        unsettled = [cell for cell, lead in leads(done, envs, modes).items()
                     if not (lead or {}).get("separated")] if more else []
        if unsettled:
            log(f"[report] {len(unsettled)} cells whose top two the seeds {cfg.seeds} cannot separate get seeds "
                f"{cfg.more_seeds}: " + ", ".join(f"{env} {mode}" for env, mode in unsettled), flush=True)
            combos += [(defense, env, mode, seed) for env, mode in unsettled for defense in PAPER_DEFENSES
                       for seed in more]
            first = done
            done = evaluated(cfg, store, combos, eps, sweep_attacks, log)
            done.counts = {"run": first.counts["run"] + done.counts["run"],
                           "cached": done.counts["cached"] - first.counts["run"]}
    evals = by_cell(done.plan, done.returns)
    compute = compute_summary({p for p in done.policies.values() if p},
                              {a for a in (*done.adversaries.values(), *done.directed.values()) if a},
                              [run.get("seconds") for run in done.runs])

    # 4. tables, figures, the JSON and the text
    cells, tables, overall = make_tables(evals, envs, modes, eps, store.missing)
    top = leads(done, envs, modes)
    curves = aril_rounds(done.policies)
    plot_figures(evals, curves, envs, modes, sweep_attacks, eps, figures_dir)
    gifs = render_gifs(comma_list(cfg.render_envs), modes, figures_dir, log) if cfg.render else []
    payload = {**made, "budget": cfg.budget, "seconds": round(time.time() - started, 1),
               "evaluations_run": done.counts, "evaluated_on": evaluated_on(done.runs), "compute": compute,
               "envs": envs, "modes": modes, "seeds": training_seeds,
               "seeds_per_cell": {f"{env} {mode}": sorted({s for d, e, m, s in combos if (e, m) == (env, mode)})
                                  for env in envs for mode in modes},
               "top_two": {f"{env} {mode}": lead for (env, mode), lead in top.items()},
               "eps": {f"{e} {m}": v for (e, m), v in eps.items()},
               "episode_seeds": f"{DEFENSE_TABLE}..{DEFENSE_TABLE + max(cfg.episodes, cfg.sweep_episodes) - 1}",
               "files": {_relative(p): digest(p) for p in {*done.policies.values(), *done.adversaries.values(),
                                                           *done.surrogates.values(), *done.directed.values()} if p},
               "missing": {" ".join(map(str, k)): v for k, v in store.missing.items()},
               "benchmarks": benchmarks, "aril_rounds": curves,
               "overall_drop": {m: {f"{d} {a}": v for (d, a), v in o.items()} for m, o in overall.items()},
               "evaluations": evaluations_json(done.plan, done.returns, _relative)}
    (figures_dir / "report.json").write_text(json.dumps(payload, indent=1) + "\n")
    out.write_text(report_markdown(payload, tables, cells, overall, out, gifs))
    log(f"[report] wrote {out} and {figures_dir}/ in {time.time() - started:.0f}s", flush=True)
    return out
