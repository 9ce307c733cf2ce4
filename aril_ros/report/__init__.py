"""``aril report``: ``docs/results.md`` regenerated from scratch, every figure traceable.

    aril report budget:=quick          # under ~30 min on 2 cores: the bundled policies and adversaries
    aril report budget:=full           # the paper's protocol: 3 training seeds, 50 episodes, wide sweeps

What it runs, in order:

1. **Performance** (first, on an idle machine): ``benchmarks/bench_engine.py``, ``bench_graph.py`` and
   ``bench_adversary.py`` as subprocesses, their closing JSON lines read back; ratios to raw MuJoCo.
2. **Policies and adversaries** per defense, env, mode and training seed. Seed 0 is the bundled policy
   (``aril_ros/data/<defense>/``) and the bundled ARIL-A trained against it
   (``aril_ros/data/defense-adversary/``, ``adversary/`` for DAgger); other seeds are trained here by
   the bundled policy's own command (from its provenance) with ``seed:=`` changed, then an ARIL-A
   against each, into ``<work_dir>/``, ``workers`` trainings side by side (each on one thread; a finished
   file is kept, so an interrupted run resumes). A missing or failed one makes its cells say why.
3. **Evaluations**, two at a time in spawned processes: every policy clean and under random, FGSM,
   FGSM^k and its own ARIL-A at the calibrated eps (the tables), and under the sweep attacks at
   multiples of it (the eps sweeps; ARIL-A's perturbation is scaled to each eps). Each evaluation is
   cached in ``<work_dir>/cache/`` under a key of its arguments and the files' digests, so an
   interrupted report resumes and a changed policy is evaluated again.
4. **Report**: tables in the paper's layout beside the paper's figures, sweeps and ARIL's rounds as
   PNG (matplotlib), optional GIFs of an attack (``render:=true``), the comparison with the paper.

Files written (all committed: the report is built from them)::

    docs/results.md                      the report
    docs/results/report.json             every evaluation (per-episode returns), file digests, benchmarks
    docs/results/sweep-<env>-<mode>.png  return vs eps per defense, one panel per attack
    docs/results/aril-rounds.png         ARIL's clean and attacked return per round
    docs/results/attack-<env>-<mode>.gif clean | attacked DAgger | attacked ARIL (render:=true)
"""
from __future__ import annotations

import concurrent.futures
import datetime
import hashlib
import json
import math
import multiprocessing
import os
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .adversary import defense_adversary_path
from .args import arg, command_line, parse_args
from .attacks import calibrated_eps
from .experiments import PAPER_ENVS_ARG, ROW_NAMES, _ready_adversary, _split, _trained_for
from .experts import bundled_file, git_revision
from .policy import PolicyFileError, load_weights
from .paper import PAPER, PAPER_ENV, PAPER_OVERALL, TABLE_ROWS
from .report_text import report_markdown

REPO = Path(__file__).resolve().parent.parent
DEFENSES = ("dagger", "gail", "dr", "dart", "aril")  # the paper's rows, in its order
DEFENSE_NAMES = {"dagger": "DAgger", "gail": "GAIL", "dr": "DR", "dart": "DART", "aril": "ARIL"}
THREATS = ("random", "fgsm", "fgsm_k", "aril_a")
ATTACK_ROWS = ("none", "fgsm", "fgsm_k", "aril_a")  # the Adversary rows: attacks on the DAgger learner
BUDGETS = {
    "quick": dict(seeds="0", episodes=20, sweep_episodes=10, sweep_scales="0.5,2",
                  sweep_attacks="random,fgsm,fgsm_k,aril_a", bench_steps=10_000),
    "full": dict(seeds="0,1,2", episodes=50, sweep_episodes=20, sweep_scales="0.25,0.5,1.5,2,3",
                 sweep_attacks="random,fgsm,fgsm_k,aril_a", bench_steps=50_000),
}
# Student's t, two-sided 95%, by degrees of freedom (the interval of a mean over seeds or episodes)
T95 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262, 10: 2.228,
       15: 2.131, 20: 2.086, 30: 2.042, 40: 2.021, 60: 2.000, 120: 1.980}


@dataclass
class ReportConfig:
    """Arguments of ``aril report``; 0 or empty takes the budget's value."""

    budget: str = arg("quick", "quick (bundled policies, 1 seed, 20 episodes: under ~30 min on 2 cores) or full "
                               "(3 training seeds, 50 episodes, wide sweeps: the paper's protocol, many hours; "
                               "resumable)")
    envs: str = arg(PAPER_ENVS_ARG, "comma-separated env ids")
    modes: str = arg("sensory,physical", "comma-separated attack modes")
    seeds: str = arg("", "training seeds per defense (seed 0: the bundled policies; others are trained)")
    episodes: int = arg(0, "deterministic evaluation episodes per table cell and seed (env seeds 3000...)")
    sweep_episodes: int = arg(0, "episodes per eps-sweep point and seed")
    sweep_scales: str = arg("", "eps sweep points as multiples of the calibrated eps (besides 0 and 1)")
    sweep_attacks: str = arg("", "attacks of the eps sweeps")
    adversary_steps: int = arg(1_000_000, "ARIL-A steps against each defense and seed that has no adversary yet")
    horizon: int = arg(1000, "steps per episode (the paper's 1000; fewer only for a smoke test)")
    workers: int = arg(2, "trainings and evaluations run side by side (one thread each)")
    perf: bool = arg(True, "run the benchmarks (the performance section)")
    bench_steps: int = arg(0, "steps per engine and adversary benchmark")
    render: bool = arg(False, "render GIFs of an attack (MuJoCo offscreen on the CPU) for render_envs")
    render_envs: str = arg("HalfCheetah-v5", "envs to render when render:=true (both modes each)")
    work_dir: str = arg("runs/report", "trained seeds, their adversaries and the evaluation cache")
    fresh: bool = arg(False, "ignore cached evaluations")
    out: str = arg("docs/results.md", "the report; its figures and JSON go to <out without .md>/")


def _resolved(cfg: ReportConfig) -> ReportConfig:
    if cfg.budget not in BUDGETS:
        raise ValueError(f"unknown budget {cfg.budget!r}; choose one of {', '.join(BUDGETS)}")
    values = {k: getattr(cfg, k) or v for k, v in BUDGETS[cfg.budget].items()}
    return ReportConfig(**{**cfg.__dict__, **values})


def t95(df: int) -> float:
    return T95[max(k for k in T95 if k <= max(df, 1))]


def summarise(per_seed: list[list[float]]) -> dict:
    """Mean and 95% interval of returns grouped by training seed: over the seed means when there are
    several seeds (seed-to-seed variation is what a reader wants bounded), else over the episodes."""
    means = np.array([np.mean(r) for r in per_seed])
    units = means if len(per_seed) > 1 else np.asarray(per_seed[0], dtype=float)
    half = t95(len(units) - 1) * units.std(ddof=1) / math.sqrt(len(units)) if len(units) > 1 else float("nan")
    return {"mean": float(means.mean()), "ci95": float(half), "median": float(np.median(np.concatenate(per_seed))),
            "seeds": len(per_seed), "episodes": len(per_seed[0]), "ci_over": "seeds" if len(per_seed) > 1 else "episodes"}


def _uncommitted() -> str:
    """A mark on the revision when tracked files differ from it: the figures may not be reproducible from it."""
    done = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO, capture_output=True,
                          text=True)
    return " (with uncommitted changes)" if done.returncode == 0 and done.stdout.strip() else ""


def digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:12]


def _relative(path: Path) -> str:
    path = Path(path).resolve()
    return str(path.relative_to(REPO)) if path.is_relative_to(REPO) else str(path)


FAILURES = (PolicyFileError, ValueError, RuntimeError, OSError)  # recorded as a missing file, not raised


def in_processes(fn, calls: list[tuple], workers: int):
    """``fn(*call)`` for each call, ``workers`` at a time in spawned processes (in this one for a single
    worker); yields ``(index, result or the FAILURES exception raised)`` as each finishes."""
    if workers == 1:
        for index, call in enumerate(calls):
            try:
                yield index, fn(*call)
            except FAILURES as err:
                yield index, err
        return
    with concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(fn, *call): index for index, call in enumerate(calls)}
        for future in concurrent.futures.as_completed(futures):
            err = future.exception()
            if err is not None and not isinstance(err, FAILURES):
                raise err
            yield futures[future], err if err is not None else future.result()


def train_seed(cfg: ReportConfig, defense: str, env: str, mode: str, seed: int, out: Path) -> Path:
    """Seed ``seed`` of a defense: the bundled policy's own training command with ``seed:=`` changed."""
    from .dagger import LearnerConfig, train_learner
    from .gail import GailConfig, train_gail

    words = shlex.split(load_weights(bundled_file(defense, env, mode))[0]["provenance"]["command"])
    kept = [w for w in words[2:] if w.split(":=")[0] not in ("seed", "out", "run_dir")]
    print(f"[report] training {out.stem}: {' '.join(words[:2] + kept)} seed:={seed}", flush=True)
    if defense == "gail":
        # GAIL keeps its best policy so far in its out file while it trains: train beside ``out`` so that an
        # existing ``out`` means a finished training (an interrupted report resumes from it)
        partial = out.with_name(f"{out.stem}.partial.pt")
        train_gail(parse_args(GailConfig, kept + [f"seed:={seed}", f"out:={partial}"]), log=print)
        os.replace(partial, out)
        return out
    run_dir = Path(cfg.work_dir) / "learners" / out.stem
    return Path(train_learner(parse_args(LearnerConfig, kept + [f"seed:={seed}", f"out:={out}", f"run_dir:={run_dir}"]),
                              log=print))


def train_seed_adversary(cfg: ReportConfig, env: str, mode: str, policy: Path, eps: float, out: Path) -> Path:
    _ready_adversary(out, str(policy), env, mode, eps, "expert", cfg.adversary_steps, False, print)
    return out


class Artifacts:
    """Policy and adversary files per (defense, env, mode, seed): the bundled ones for seed 0, trained
    into ``work_dir`` otherwise, ``cfg.workers`` at a time. A file that cannot be had is recorded in
    ``missing`` with the reason."""

    def __init__(self, cfg: ReportConfig, log):
        self.cfg, self.log, self.work = cfg, log, Path(cfg.work_dir)
        self.missing: dict[tuple, str] = {}

    def _prepare(self, kind: str, wanted: dict[tuple, Path | Exception], fn, calls: dict[Path, tuple]) -> dict:
        """``wanted`` maps each combo to its file (or the error that stops it); ``calls`` makes the files
        not there yet (one call per file: a mode-independent policy is shared by both modes)."""
        made = {out: out for out in calls if out.exists()}
        todo = [out for out in calls if out not in made]
        if todo:
            self.log(f"[report] {len(todo)} {kind} files to train, {self.cfg.workers} at a time", flush=True)
        for index, result in in_processes(fn, [calls[out] for out in todo], self.cfg.workers):
            made[todo[index]] = result
        files = {}
        for combo, file in wanted.items():
            result = made.get(file, file)
            if isinstance(result, Exception):
                self.missing[(kind, *combo)] = str(result)
                self.log(f"[report] no {kind} for {' '.join(map(str, combo))}: {result}", flush=True)
                result = None
            files[combo] = result
        return files

    def policies(self, combos: list[tuple]) -> dict[tuple, Path | None]:
        """Each (defense, env, mode, seed)'s policy file, or None."""
        wanted, calls = {}, {}
        for defense, env, mode, seed in combos:
            try:
                bundled = bundled_file(defense, env, mode)
            except FAILURES as err:
                wanted[(defense, env, mode, seed)] = err
                continue
            if seed == 0:
                wanted[(defense, env, mode, seed)] = bundled
                continue
            name = f"{defense}-{env}{f'-{mode}' if defense in ('dr', 'aril') else ''}-seed{seed}"
            out = self.work / "policies" / f"{name}.pt"
            wanted[(defense, env, mode, seed)] = out
            calls.setdefault(out, (self.cfg, defense, env, mode, seed, out))
        return self._prepare("policy", wanted, train_seed, calls)

    def adversaries(self, policies: dict[tuple, Path | None], eps: dict[tuple, float]) -> dict[tuple, Path | None]:
        """The ARIL-A trained against each policy: the bundled one for seed 0 (when made for this eps)."""
        wanted, calls = {}, {}
        for (defense, env, mode, seed), policy in policies.items():
            if policy is None:
                continue
            bundled = defense_adversary_path(env, mode, defense)
            if seed == 0 and _trained_for(bundled, eps[env, mode]):
                wanted[(defense, env, mode, seed)] = bundled
                continue
            out = self.work / "adversaries" / f"{env}-{mode}-{defense}-seed{seed}.pt"
            wanted[(defense, env, mode, seed)] = out
            calls[out] = (self.cfg, env, mode, policy, eps[env, mode], out)
        return self._prepare("adversary", wanted, train_seed_adversary, calls)


def _evaluate_job(job: dict) -> list[float]:
    from .evaluation import EvalConfig, evaluate

    return evaluate(EvalConfig(**job))["returns"]


def _job_key(job: dict) -> str:
    files = {k: digest(Path(job[k])) for k in ("policy", "attack_file") if job.get(k)}
    return hashlib.sha256(json.dumps([job, files], sort_keys=True).encode()).hexdigest()[:20]


def run_jobs(jobs: list[dict], cfg: ReportConfig, log) -> tuple[list[list[float]], dict]:
    """Per-episode returns of each evaluation, from the cache or computed ``cfg.workers`` at a time, and how
    many distinct evaluations were run and read from the cache. Equal jobs (a mode-independent policy's
    clean run, asked for by both modes) run once."""
    cache = Path(cfg.work_dir) / "cache"
    cache.mkdir(parents=True, exist_ok=True)
    keys = [_job_key(job) for job in jobs]
    done: dict[str, list[float]] = {}
    todo: dict[str, dict] = {}
    for key, job in zip(keys, jobs):
        hit = cache / f"{key}.json"
        if hit.exists() and not cfg.fresh:
            done[key] = json.loads(hit.read_text())["returns"]
        else:
            todo[key] = job
    counts = {"run": len(todo), "cached": len(done)}
    log(f"[report] {len(jobs)} evaluations: {len(done)} cached, {len(todo)} to run", flush=True)
    started = time.time()
    todo_keys = list(todo)
    for n, (index, returns) in enumerate(in_processes(_evaluate_job, [(todo[k],) for k in todo_keys], cfg.workers), 1):
        if isinstance(returns, Exception):
            raise returns
        key = todo_keys[index]
        job, done[key] = todo[key], returns
        (cache / f"{key}.json").write_text(json.dumps({"job": job, "returns": done[key]}))
        log(f"[report] {n}/{len(todo)} {time.time() - started:6.0f}s  {job['env']} {job['mode']} "
            f"{Path(job['policy']).name} {job['attack']} eps {job['eps']:g}: {np.mean(done[key]):.1f}", flush=True)
    return [done[key] for key in keys], counts


def run_benchmarks(cfg: ReportConfig, log) -> dict:
    """The three benchmarks, back to back in this run; each one's closing JSON line."""
    env = "HalfCheetah-v5"
    commands = {
        "engine": ["benchmarks/bench_engine.py", f"env:={env}", f"steps:={cfg.bench_steps}"],
        "graph": ["benchmarks/bench_graph.py", f"env:={env}", f"steps:={max(cfg.bench_steps // 10, 1000)}",
                  "seconds:=3"],
        "adversary": ["benchmarks/bench_adversary.py", f"env:={env}", f"steps:={max(cfg.bench_steps * 4, 16384)}"],
    }
    figures = {}
    for name, command in commands.items():
        log(f"[report] benchmark: python {' '.join(command)}", flush=True)
        done = subprocess.run([sys.executable, *command], cwd=REPO, capture_output=True, text=True)
        lines = [ln for ln in done.stdout.splitlines() if ln.startswith("{")]
        if done.returncode or not lines:
            figures[name] = {"error": (done.stderr.strip().splitlines() or ["no output"])[-1],
                             "command": " ".join(command)}
            continue
        figures[name] = {**json.loads(lines[-1]), "command": "python " + " ".join(command)}
    return figures


def _cell(results: dict, defense: str, attack: str) -> dict | None:
    per_seed = results.get((defense, attack))
    return summarise(per_seed) if per_seed else None


def table_cells(evals: dict, env: str, mode: str) -> dict:
    """Each table row's summary for one env and mode; defenses under their worst attack (by mean)."""
    results = {(d, a): r for (e, m, d, a, scale), r in evals.items() if e == env and m == mode and scale in (0.0, 1.0)}
    cells = {}
    for defense, attack in TABLE_ROWS:
        if attack != "worst":
            cells[(defense, attack)] = _cell(results, defense, attack)
            continue
        candidates = {t: c for t in THREATS if (c := _cell(results, defense, t))}
        if not candidates:
            cells[(defense, attack)] = None
            continue
        worst = min(candidates, key=lambda t: candidates[t]["mean"])
        cells[(defense, attack)] = {**candidates[worst], "attack": worst,
                                    "clean": (_cell(results, defense, "none") or {}).get("mean")}
    return cells


def _fmt_paper(mode: str, row: tuple, env: str) -> str:
    figure = PAPER[mode].get(row, {}).get(env)
    if figure is None:
        return "—"
    return f"{figure[0]:,}" + ("" if row == ("dagger", "none") else f" ({figure[1]:+.1f}%)")


def _row_label(row: tuple) -> str:
    defense, attack = row
    if defense == "dagger":
        return "DAgger, clean" if attack == "none" else f"{ROW_NAMES[attack]} (on DAgger)"
    return DEFENSE_NAMES[defense]


def table_markdown(mode: str, envs: list[str], cells: dict, eps: dict, missing: dict) -> tuple[list[str], dict]:
    """The paper's layout: our figure (95% interval, drop, worst attack) beside the paper's, per env."""
    header = ("| | " + " | ".join(f"{e} ours (eps {eps[e]:g}) | {PAPER_ENV[e]} paper" for e in envs)
              + " | overall ours | overall paper |")
    lines = [header, "|---|" + "---|---|" * len(envs) + "---|---|"]
    overall = {}
    for row in TABLE_ROWS:
        parts, drops = [], []
        for env in envs:
            cell = cells[env].get(row)
            reference = (cells[env].get(("dagger", "none")) or {}).get("mean")
            if cell is None:
                why = next((v for k, v in missing.items() if k[1:4] == (row[0], env, mode)), "not evaluated")
                parts.append(f"missing: {why[:80]}")
            else:
                drop = 100.0 * (cell["mean"] / reference - 1.0) if reference else float("nan")
                drops.append(drop)
                text = f"{cell['mean']:.0f} ± {cell['ci95']:.0f}"
                if row != ("dagger", "none"):
                    text += f" ({drop:+.1f}%{', ' + ROW_NAMES[cell['attack']] if 'attack' in cell else ''})"
                parts.append(text)
            parts.append(_fmt_paper(mode, row, env))
        overall[row] = sum(drops) / len(drops) if len(drops) == len(envs) else None
        paper_overall = PAPER_OVERALL[mode].get(row)
        lines.append(f"| {_row_label(row)} | " + " | ".join(parts)
                     + f" | {'—' if overall[row] is None else f'{overall[row]:+.1f}%'}"
                     + f" | {'—' if paper_overall is None else f'{paper_overall:+.1f}%'} |")
    return lines, overall


def plot_sweeps(evals: dict, env: str, mode: str, attacks: list[str], eps0: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(attacks), figsize=(4.2 * len(attacks), 3.4), squeeze=False)
    for ax, attack in zip(axes[0], attacks):
        for defense in DEFENSES:
            points = sorted((scale, summarise(r)) for (e, m, d, a, scale), r in evals.items()
                            if e == env and m == mode and d == defense and a in (attack, "none"))
            if not points:
                continue
            x = [scale * eps0 for scale, _ in points]
            y = np.array([s["mean"] for _, s in points])
            ci = np.nan_to_num(np.array([s["ci95"] for _, s in points]))
            ax.plot(x, y, marker="o", ms=3, label=DEFENSE_NAMES[defense])
            ax.fill_between(x, y - ci, y + ci, alpha=0.15)
        ax.axvline(eps0, color="grey", lw=0.8, ls=":")
        ax.set_title(f"{ROW_NAMES[attack]}")
        ax.set_xlabel("eps (dotted: calibrated)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("return")
    axes[0][-1].legend(fontsize=8)
    fig.suptitle(f"{env}, {mode} attacks: return vs eps (mean, 95% interval)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _command_arg(command: str, key: str, default: str | None = None) -> str:
    found = [word.split(":=", 1)[1] for word in shlex.split(command) if word.startswith(f"{key}:=")]
    if not found and default is None:
        raise ValueError(f"{key}:= is not in the command {command!r}")
    return found[0] if found else default


def aril_rounds(artifacts: dict) -> dict:
    """ARIL's per-round clean and attacked return, from each ARIL policy file's provenance."""
    curves = {}
    for (defense, env, mode, seed), path in artifacts.items():
        if defense != "aril" or path is None:
            continue
        provenance = load_weights(path)[0]["provenance"]
        rounds = provenance.get("rounds_log", [])
        curves[f"{env} {mode} seed {seed}"] = {
            "round": [r["round"] for r in rounds], "attacked": [r["return"] for r in rounds],
            "clean": [r.get("clean_return", r["return"]) for r in rounds],  # round 0: the expert's clean demos
            "selected": provenance.get("selected"), "adversary_steps": int(_command_arg(provenance["command"], "adversary_steps")),
            "warm_start": _command_arg(provenance["command"], "warm_start", "False") == "True"}
    return curves


def plot_rounds(curves: dict, envs: list[str], modes: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(modes), len(envs), figsize=(4.2 * len(envs), 3.0 * len(modes)), squeeze=False)
    for i, mode in enumerate(modes):
        for j, env in enumerate(envs):
            ax = axes[i][j]
            for name, curve in curves.items():
                if not name.startswith(f"{env} {mode} "):
                    continue
                seed = name.rsplit(" ", 1)[-1]
                ax.plot(curve["round"], curve["clean"], marker="o", ms=3, label=f"clean, seed {seed}")
                ax.plot(curve["round"], curve["attacked"], marker="s", ms=3, ls="--", label=f"under f_t, seed {seed}")
                if curve["selected"]:
                    ax.axvline(int(curve["selected"].split("_")[1]), color="grey", lw=0.8, ls=":")
            ax.set_title(f"{env} {mode}", fontsize=9)
            ax.set_xlabel("round (dotted: returned policy)")
            ax.grid(alpha=0.3)
            if j == 0:
                ax.set_ylabel("return")
    axes[0][-1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def build_report(cfg: ReportConfig, log=print) -> Path:
    cfg = _resolved(cfg)
    started = time.time()
    envs, modes = _split(cfg.envs), _split(cfg.modes)
    seeds = [int(s) for s in _split(cfg.seeds)]
    scales = [float(s) for s in _split(cfg.sweep_scales)]
    if cfg.workers < 1 or cfg.horizon < 1:
        raise ValueError("workers:= and horizon:= must be at least 1")
    if any(s <= 0 or s == 1.0 for s in scales):
        raise ValueError(f"sweep_scales:= takes multiples other than 0 and 1 (those are the tables'), got {scales}")
    sweep_attacks = _split(cfg.sweep_attacks)
    out = Path(cfg.out)
    figures_dir = out.with_suffix("")
    figures_dir.mkdir(parents=True, exist_ok=True)
    stamp = {"command": command_line("aril report", cfg), "git_revision": git_revision() + _uncommitted(),
             "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
             "cores": os.cpu_count()}
    benchmarks = run_benchmarks(cfg, log) if cfg.perf else {}

    store = Artifacts(cfg, log)
    eps = {(env, mode): calibrated_eps(env, mode) for env in envs for mode in modes}
    policies = store.policies([(defense, env, mode, seed) for env in envs for mode in modes
                               for defense in DEFENSES for seed in seeds])
    adversaries = store.adversaries(policies, eps)
    jobs, keys = [], []
    for (defense, env, mode, seed), policy in policies.items():
        if policy is None:
            continue
        adversary = adversaries[(defense, env, mode, seed)]
        plan = [("none", 0.0, cfg.episodes)] + [(t, 1.0, cfg.episodes) for t in THREATS]
        plan += [(a, s, cfg.sweep_episodes) for a in sweep_attacks for s in scales]
        for attack, scale, episodes in plan:
            if attack == "aril_a" and adversary is None:
                continue
            jobs.append({"env": env, "policy": str(policy), "mode": "clean" if attack == "none" else mode,
                         "attack": attack, "eps": round(scale * eps[env, mode], 6),
                         "attack_file": str(adversary) if attack == "aril_a" else "",
                         "rescale": attack == "aril_a", "episodes": episodes, "seed": 3000,
                         "horizon": cfg.horizon})
            keys.append((env, mode, defense, attack, scale, seed))
    returns, counts = run_jobs(jobs, cfg, log)
    evals: dict[tuple, list[list[float]]] = {}
    for (env, mode, defense, attack, scale, seed), r in zip(keys, returns):
        evals.setdefault((env, mode, defense, attack, scale), []).append(r)

    tables, overall, cells = {}, {}, {}
    for mode in modes:
        cells[mode] = {env: table_cells(evals, env, mode) for env in envs}
        tables[mode], overall[mode] = table_markdown(mode, envs, cells[mode], {e: eps[e, mode] for e in envs},
                                                     store.missing)
        for env in envs:
            plot_sweeps(evals, env, mode, sweep_attacks, eps[env, mode], figures_dir / f"sweep-{env}-{mode}.png")
    curves = aril_rounds(policies)
    plot_rounds(curves, envs, modes, figures_dir / "aril-rounds.png")
    gifs = []
    if cfg.render:
        from .render import RenderConfig, render

        for env in _split(cfg.render_envs):
            for mode in modes:
                gifs.append(render(RenderConfig(env=env, mode=mode, width=240, height=180, steps=240, every=4,
                                                out=str(figures_dir / f"attack-{env}-{mode}.gif")), log=log))

    files = {_relative(p): digest(p) for p in {*policies.values(), *adversaries.values()} if p is not None}
    payload = {**stamp, "budget": cfg.budget, "seconds": round(time.time() - started, 1),
               "evaluations_run": counts, "envs": envs,
               "modes": modes, "seeds": seeds, "eps": {f"{e} {m}": v for (e, m), v in eps.items()},
               "episode_seeds": f"3000..{3000 + max(cfg.episodes, cfg.sweep_episodes) - 1}",
               "files": files, "missing": {" ".join(map(str, k)): v for k, v in store.missing.items()},
               "benchmarks": benchmarks, "aril_rounds": curves,
               "overall_drop": {m: {f"{d} {a}": v for (d, a), v in o.items()} for m, o in overall.items()},
               "evaluations": [{"key": dict(zip(("env", "mode", "defense", "attack", "scale", "seed"), k)),
                                "job": {**j, "policy": _relative(Path(j["policy"])),
                                        "attack_file": j["attack_file"] and _relative(Path(j["attack_file"]))},
                                "mean": float(np.mean(r)), "returns": r} for k, j, r in zip(keys, jobs, returns)]}
    (figures_dir / "report.json").write_text(json.dumps(payload, indent=1) + "\n")
    out.write_text(report_markdown(payload, tables, cells, overall, out, gifs))
    log(f"[report] wrote {out} and {figures_dir}/ in {time.time() - started:.0f}s", flush=True)
    return out
