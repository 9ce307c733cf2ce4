"""``aril scorecard``: how robust is this policy? One command, one page.

    aril scorecard policy:=runs/my-policy.pt env:=HalfCheetah-v5 modes:=sensory,physical budget:=quick

For each attacked mode: the clean return and every attack's return on the same env seeds (paired: episode ``i``
resets with seed ``seed + i`` in every cell), the drop from clean with a paired Student-t 95% interval, an eps sweep
per attack (the budget's: eps alone for quick; 0.5, 1 and 2 x eps for full; through the graph, where each cell
is a run, of the mode's worst attack at eps alone), the worst case at eps, and the
expert disagreement ``||a - a_e||^2`` of each cell. The attacks: random noise; the black-box ones, which only ask the
policy for actions:
SPSA^k, FGSM by finite differences (the sign of the loss's slope along each perturbed entry, from two questions per
entry) and what the black-box pipeline (:mod:`aril_ros.verdict`) makes: FGSM^k on a surrogate fitted to the policy's
answers (transfer), the zoo's strongest bundled ARIL-A (none trained against this very file), ARIL-A trained
from it against the policy's answers, alone and with query-time search, and a directed ARIL-A trained against them
(its actor asks the policy for its action's slope along each perturbed entry); and, when the policy is a file whose
gradients can be taken, the white-box FGSM and FGSM^k. The worst of
them is the verdict (AutoAttack's rule: no knob a user could set to a soft verdict). eps is the calibrated one for
the env and mode unless ``eps:=`` sets it. A bundled name trained per attack mode (dr, aril) is another file in each
mode, each with a clean cell of its own (a drop compares the same policy clean and attacked).

A policy file or a bundled name is scored on the in-process engine, its cells as sweep tasks (:mod:`aril_ros.sweep`:
``workers`` CPUs of a local Ray, or a cluster at ``address``), after its black-box pipeline; with ``via:=graph`` each
cell is instead a run of the ROS 2 graph with a policy node serving the file (the verdict through the nodes a robot
runs, the same figures: the graph is bit-exact to the engine), each run a sweep task of :data:`~aril_ros.cell_runner.GRAPH_RUN_CPUS` CPUs
on its node, in a ROS domain of its own there, its log coming back with ``keep_logs:=true``. ``policy:=external``
scores a ROS 2 policy node you run yourself (msgs_doc/README.md, "Write your own policy node"): every cell is a run of the graph with
your node in the loop, and the surrogate is fitted to its answers, and ARIL-A trained against them, through the same
topics (never its weights).
Start the node in a domain of your choosing and name it::

    ROS_DOMAIN_ID=42 ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST python my_policy.py --ros-args -p act_dim:=6 &
    aril scorecard policy:=external domain:=42 env:=HalfCheetah-v5

The node must keep answering from run to run (the runs follow one another in that domain).

Everything goes to one folder (``out:=``, default ``runs/scorecard-<env>-<policy name>/``)::

    scorecard.md             the page: per mode a table and the sweep figure
    scorecard.json           the settings and every episode of every cell: return, expert loss, steps, max|delta|;
                             per cell its attack's questions to the policy, in all and per step (queries,
                             queries_per_step: on the engine as the attack counted them, through the graph the
                             probes the node answered);
                             for a name trained per mode, the file scored in each mode; per mode the pipeline's
                             files, the surrogate's questions and fidelity, the zoo screened (best first), ARIL-A's
                             training questions, the state of it the rows used and its states judged (best first;
                             each state's return in each scored episode)
    sweep-<mode>.png         return against eps per attack, with the clean return and 95% intervals
    surrogate-<mode>.pt      the black-box pipeline's copy of the policy (aril_ros.verdict); a rerun reuses it (same
                             policy, eps, horizon; for an external node: another node needs another out:= folder)
    adversary-<mode>.pt      the ARIL-A trained against the policy from the zoo's strongest; a rerun reuses it
                             (same policy, eps, horizon, steps)
    directed-<mode>.pt       the directed ARIL-A trained against the policy; a rerun reuses it (same policy, eps,
                             steps)
    <adversary|directed>-<mode>-at-<steps>.pt
                             the states those trainings kept before their end (aril_ros.verdict.SNAPSHOT_EVERY):
                             the rows use whichever of them and the end took the most return from the policy on
                             the scored episodes
    logs/<mode>-<attack>[-<file>][-search<K>]-<eps>.mcap
                             through the graph (policy:=external, via:=graph) with keep_logs:=true: each graph run's
                             log

A rerun with the same settings reuses the surrogates and the trained adversaries, so an interrupted scorecard
resumes from its evaluations at most.

This module is the plan: the arguments, the cells (mode, attack, eps) and the adversaries they need, and the
worst case of each mode. :mod:`aril_ros.cell_runner` runs the cells (the sweep's progress lines give the ETA);
:mod:`aril_ros.report` renders them: the paired drops (``report.stats``), the page (``report.text``) and the
figures (``report.plots``).
"""
from __future__ import annotations

import dataclasses
import json
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path

from . import plugins, seeds
from .args import arg, comma_list
from .cell_runner import GRAPH_RUN_CPUS, CellRunner
from .envs import HORIZON
from .evaluation import EvalConfig
from .policy import load_policy, resolve_policy
from .protocol import checked_domain
from .provenance import stamp
from .registry import (
    ATTACKED_MODES,
    SCORECARD_ATTACKS,
    SEARCH_ROW,
    DIRECTED_ROW,
    DEFAULT_ENV,
    MAX_EPS,
    PER_MODE_POLICIES,
    WHITE_BOX,
    bundled_file,
    calibrated_eps,
    check_name,
    row_attack,
)
from .report.plots import plot_scorecard_sweep
from .report.stats import paired_drop, worst_attack
from .report.text import scorecard_markdown
from .sweep import session
from .timing import LEARNED_TIMING_ROW, TIMING_ROWS
from .adversary import AdversaryConfig, ready_adversaries
from .adversary_net import load_adversary
from .verdict import SEARCH, BlackBoxAttacks, Trained, directed_pipeline, pipeline, relative, run_pipelines


@dataclass(frozen=True)
class Budget:
    """How much a scorecard spends: episodes per cell, ARIL-A's training steps per mode, and the query attacks'
    questions per step (SPSA^k's ``1 + spsa_iterations * (2 * spsa_samples + 1)``, fd_fgsm's
    ``fd_iterations * (2 entries + 1) + 1``): through the graph each one is a message to the node and back, so they,
    not the steps, set the time of an external node's query cells."""

    episodes: int
    adversary_steps: int
    spsa_iterations: int
    spsa_samples: int
    fd_iterations: int
    """fd_fgsm's iterations (one probe batch each): on the 8 sensory screening cells one took at least as much as
    FGSM^k's 10 in 6 and, where 10 took more, the directed ARIL-A took more still (results/aril_a_tuning.md, issue 38)"""
    scales: str
    """the eps sweep, as multiples of the mode's eps (the default of ``scales:=``)"""
    black_box: dict | None = None
    """per mode the black-box rows it scores unless ``attacks:=`` names others (None: every one); the white-box rows
    of a file are scored beside them"""
    timing: tuple[str, ...] = ()
    """the timing rows it scores (:data:`aril_ros.timing.TIMING_ROWS`), the policy otherwise clean: the quick budget
    the delay alone (an external node's quick verdict stays within minutes: each row is a graph run), the full one
    every one"""
    timing_adversary_steps: int = 0
    """the learned timing row's PPO steps: its adversary trains against the file (an external node: against the
    pipeline's surrogate, at the engine's speed)"""

    @property
    def spsa_queries(self) -> int:
        return 1 + self.spsa_iterations * (2 * self.spsa_samples + 1)

    def describe(self) -> str:
        return (f"{self.episodes} episodes per cell, ARIL-A trained {self.adversary_steps:,} steps per mode against "
                f"the policy's answers, SPSA^k "
                f"{self.spsa_iterations} x {self.spsa_samples} directions, {self.spsa_queries} queries per step"
                f"{self.where_named('spsa')}, FGSM by finite differences {self.fd_iterations} "
                f"iteration{'s' if self.fd_iterations != 1 else ''}{self.where_named('fd_fgsm')}")

    def where_named(self, row: str) -> str:
        """How the budget scores ``row``: in every mode, in some, or only where ``attacks:=`` names it."""
        modes = [mode for mode, rows in (self.black_box or {}).items() if row not in rows]
        if not modes:
            return ""
        return (" (where attacks:= names it)" if len(modes) == len(self.black_box)
                else f" (in {', '.join(modes)} mode where attacks:= names it)")


SCORED_ATTACKS = ("random", "spsa", "fd_fgsm", "transfer", "zoo", "aril_a", SEARCH_ROW, DIRECTED_ROW, "fgsm", "fgsm_k")
"""In the order the page lists them: noise, the black-box attacks, the white-box ones (a file's alone)."""
SURROGATE_ATTACKS = ("transfer", "zoo", "aril_a", SEARCH_ROW)
"""The rows that need the files of the black-box pipeline's first four steps (:func:`aril_ros.verdict.pipeline`: the
surrogate, the zoo's best, ARIL-A)."""
PIPELINE_ATTACKS = (*SURROGATE_ATTACKS, DIRECTED_ROW)
"""The rows that need the black-box pipeline's files (:mod:`aril_ros.verdict`): the directed row needs only its own
step's (:func:`~aril_ros.verdict.directed_pipeline`)."""
QUICK_ROWS = {"sensory": ("fd_fgsm", DIRECTED_ROW), "physical": ("aril_a",)}
"""The quick budget's black-box rows, so that an external node's quick verdict takes minutes. Chosen on screening
episodes (results/verdict-screening/verdict.md, 16 cells of HalfCheetah and Ant: the benchmark's fewest rows that
find 0.95 of every row's drop; results/aril_a_tuning.md, issue 38): with the aril_a rows running the stronger of the
zoo's best and the trained ARIL-A, the rows left out (random, SPSA^k, transfer and the zoo in both modes, FGSM by
finite differences, search and the directed ARIL-A in physical mode) lifted no cell's verdict to 0.9 of the
reference. fd_fgsm (one iteration: 16 questions a step on HalfCheetah, 26 on Ant, one probe batch) took the place of
transfer once every screening cell had scored it (Ant BC -60.8% against -53.9%, HalfCheetah ARIL -8.2% against
-5.3%); the directed ARIL-A (trained 500k steps from fresh weights) took the place of ARIL-A + search once every
cell had scored it too: it took more in all 8 sensory cells (Ant DAgger -57.0% against -34.4%, Ant DR -33.9% against
-15.3%, HalfCheetah DR -30.9% against -27.2%, HalfCheetah ARIL -7.3% against -6.7%), so a sensory verdict needs no
surrogate, zoo or categorical ARIL-A. In physical mode it took more than ARIL-A in 2 of the 8 cells (Ant DAgger
-83.3% against -70.2%, Ant ARIL -68.4% against -65.0%); the fewest rows there were the zoo's and ARIL-A's (ARIL-A
trained against the surrogate in those cells; with pipeline 4, ARIL-A's alone: results/verdict-screening/pipeline4),
and on pipeline 4's 8 physical screening cells, with the directed row as the pipeline makes it, ARIL-A's alone (the
directed row took at most 2.2 points more, Ant DR -68.6% against -66.4%)."""
FULL_ROWS = {"sensory": ("fd_fgsm", DIRECTED_ROW), "physical": ("zoo", "aril_a")}
"""The full budget's black-box rows, so that an external node's full verdict, with its 2M-step trainings, takes under
an hour: the quick budget's, with the zoo in physical mode. Chosen on screening episodes (results/verdict-screening,
issue 38: its 16 quick cells, where every row was scored), as the quick budget's are, by the benchmark's fewest rows
that find 0.95 of every row's drop (or of the reference's) in each cell. In each of the 8 sensory cells fd_fgsm or the
directed ARIL-A took the most, but in HalfCheetah BC's (the zoo -105.2% against the directed ARIL-A's -104.1%), so a
sensory verdict needs no surrogate, zoo or categorical ARIL-A. In physical mode the zoo and ARIL-A are the fewest
(Ant ARIL: the zoo -71.4%, ARIL-A -65.0%, the directed ARIL-A -68.4%). Left out there: ARIL-A + search, which took
the most in Ant BC's (-97.7% against the zoo's -90.6%, where the reference was -82.2%) and costs 9 questions a step
(a full row until 2026-12-07); the directed ARIL-A, which took the most in Ant DAgger's (-83.3% against
the zoo's -77.6%, whose reference was -77.7%), but whose 2M-step training is a third beside the two modes' on 2
cores (against an external node the first two took 14 and 16 min before the third had a core, a verdict on course
for over the hour: issue 38, 2026-12-07, stopped). Random noise and transfer led no cell in either mode; SPSA^k (at
5 x 8) led two sensory cells by at most 0.4 points over another row, and in physical mode a learned adversary's row
took 13 to 79 points more than it; fd_fgsm took less than FGSM^k in physical mode on the DAgger learners
(results/attacks_physical.md: -36.0% overall against -41.6%, ARIL-A -82.8%). ``attacks:=`` scores any other where
wanted."""
# quick: the verdict at eps alone, in minutes against an external node (ARIL-A trains against its answers, 16 rows a
# message); full: twice the episodes, the eps sweep at half and twice eps (through the graph each scale of a mode's
# worst row is as many runs as a row; 0.25 eps, scored until 2026-12-07, showed the least), SPSA^k at its own 5 x 8
# where named, and twice the paper's 1M steps
BUDGETS = {"quick": Budget(episodes=10, adversary_steps=500_000, spsa_iterations=1, spsa_samples=2, fd_iterations=1,
                           scales="1", black_box=QUICK_ROWS, timing=("delay",)),
           "full": Budget(episodes=20, adversary_steps=2_000_000, spsa_iterations=5, spsa_samples=8,
                          fd_iterations=1, scales="0.5,1,2", black_box=FULL_ROWS,
                          timing=tuple(TIMING_ROWS), timing_adversary_steps=500_000)}
VIAS = ("engine", "graph")


@dataclass
class ScorecardConfig:
    """Arguments of ``aril scorecard``."""

    policy: str = arg("bundled", "the policy to score: a policy file, a bundled name (dagger, aril, ...), or external "
                                 "(your ROS 2 policy node, running in domain:=)")
    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    modes: str = arg(",".join(ATTACKED_MODES), "comma-separated attacked modes: sensory, physical")
    budget: str = arg("quick", f"{' or '.join(BUDGETS)}: " + "; ".join(
        f"{name} {b.describe()}" for name, b in BUDGETS.items()))
    eps: float = arg(0.0, "the attack budget at scale 1 (0: the calibrated one for the env and each mode)",
                     low=0.0, high=MAX_EPS)
    expert: str = arg("expert", "the expert whose action on the true state is the disagreement's reference")
    scales: str = arg("", "the eps sweep: comma-separated multiples of eps, 1 among them (the worst case is judged "
                          "at eps; through the graph the other multiples run for each mode's worst attack alone); "
                          "default: the budget's (" + "; ".join(f"{n} {b.scales}" for n, b in BUDGETS.items())
                      + ")")
    attacks: str = arg("", "comma-separated attacks to score (default: every one that applies: "
                           f"{', '.join(SCORED_ATTACKS)}; an external node not the white-box {', '.join(WHITE_BOX)})")
    via: str = arg("", "where the cells run: engine (in this process or as sweep tasks: the fast path) or graph (each "
                       "cell a run of the ROS 2 graph; for a file, its own policy node, a sweep task of "
                       f"{GRAPH_RUN_CPUS} CPUs in a ROS domain of its own); default: graph for policy:=external, which "
                       "only the graph reaches, else engine")
    domain: str = arg("", "policy:=external: the ROS_DOMAIN_ID your node runs in, which every run joins")
    leave_out: str = arg("", "policy:=external: a policy file or bundled name the node serves, whose adversaries the zoo "
                             "leaves out (as it does for a file scored itself); unset, the zoo keeps every one")
    keep_logs: bool = arg(False, "through the graph: keep each graph run's log under <out>/logs/")
    seed: int = arg(seeds.SCORECARD, "env seed of the first episode (every cell runs the same episodes)",
                    low=0, high=2**31 - 1)
    episodes: int = arg(0, "episodes per cell instead of the budget's (0: the budget's)", low=0, high=100_000)
    adversary_steps: int = arg(0, "ARIL-A's training steps per mode instead of the budget's (0: the budget's)",
                               low=0, high=10**9)
    horizon: int = arg(HORIZON, "steps per episode", low=1, high=1_000_000)
    timing: int = arg(1, "the timing rows' budget k (0: no timing rows): the policy, clean otherwise, with every "
                         "observation k steps late (both budgets), every action k steps late and k tenths of its "
                         "observations dropped, whenever allowed and when a learned timing adversary picks (full)",
                      low=0, high=9)
    timing_steps: int = arg(0, "the learned timing row's adversary's training steps instead of the budget's (0: the "
                               "budget's)", low=0, high=10**9)
    workers: int = arg(2, "CPUs of the local Ray that a policy file's or bundled name's cells, and the black-box "
                          "pipeline's ARIL-A trainings, run on as tasks (1: one after the other in this process); an "
                          "external node's cells run one after the other", low=1, high=1024)
    address: str = arg("", "a policy file or bundled name: run its cells on this Ray cluster instead (<head ip>:6379, "
                           "or auto)")
    out: str = arg("", "the folder to write (default runs/scorecard-<env>-<policy name>)")


def scorecard(cfg: ScorecardConfig, log=print) -> Path:
    """Score the policy mode by mode, write the folder, return the page's path."""
    budget, modes, attacks, scales = check_config(cfg)
    out = Path(cfg.out or f"runs/scorecard-{cfg.env}-{Path(cfg.policy).stem}")
    out.mkdir(parents=True, exist_ok=True)
    eps = {mode: cfg.eps or calibrated_eps(cfg.env, mode) for mode in modes}
    runner = runner_of(cfg, out)
    # the policy under test in each mode: a per-mode name is another file in each, and each mode's drops compare
    # that very file clean and attacked; any other policy is one, whose one clean cell serves every mode
    policies = {mode: policy_in(cfg.policy, cfg.env, mode) for mode in modes}
    tested = list(dict.fromkeys(policies.values()))
    with nullcontext() if cfg.policy == "external" else session(cfg.workers, cfg.address):
        # the clean cells first (the same episodes as every other cell): an external node that waits for the run's
        # listeners before it subscribes (msgs_doc's) is then subscribed when ARIL-A's training asks it alone
        cleans = runner.run([cell(cfg, budget, "clean", "none", 0.0, policy=policy) for policy in tested], log,
                            "scorecard clean cell" + ("s" if len(tested) > 1 else ""))
        clean = dict(zip(tested, cleans))
        timed = [(policy, row) for policy in tested for row in (budget.timing if cfg.timing else ())
                 if row != LEARNED_TIMING_ROW]
        late = runner.run([timing_cell(cfg, budget, policy, row) for policy, row in timed], log,
                          "scorecard timing cells") if timed else []
        made = pipelines_for(cfg, modes, eps, budget, out, log,
                             {mode: rows_of(cfg, budget, attacks, mode, None) for mode in modes})
        if cfg.timing and LEARNED_TIMING_ROW in budget.timing:
            learned = timing_adversaries(cfg, budget, tested, made, out, log)
            late += runner.run([timing_cell(cfg, budget, policy, LEARNED_TIMING_ROW, file)
                                for policy, file in learned.items()], log, "scorecard learned timing cells")
            timed += [(policy, LEARNED_TIMING_ROW) for policy in learned]
        rows = {mode: rows_of(cfg, budget, attacks, mode, made.get(mode)) for mode in modes}
        # on the engine every row's sweep at once; through the graph each cell is a run, so every row at eps (the
        # verdict), then the sweep of each mode's worst row alone
        swept_later = via_of(cfg) == "graph"
        first = [(mode, attack, scale) for mode in modes for attack in rows[mode] for scale in scales
                 if scale == 1.0 or not swept_later]
        figures = run_cells(cfg, budget, runner, first, eps, made, log)
        if swept_later:
            worst = {mode: worst_case(clean[policies[mode]], {a: {1.0: figures[mode, a, 1.0]} for a in rows[mode]})
                     for mode in modes}
            figures |= run_cells(cfg, budget, runner, [(mode, worst[mode]["attack"], scale) for mode in modes
                                                       for scale in scales if scale != 1.0], eps, made, log)
    results = {}
    for mode in modes:
        mode_cells = {attack: {scale: figures[mode, attack, scale] for scale in scales
                               if (mode, attack, scale) in figures} for attack in rows[mode]}
        mode_clean = clean[policies[mode]]
        results[mode] = {"eps": eps[mode], "eps_source": "eps:=" if cfg.eps else "calibrated",
                         **({"policy": policies[mode]} if policies[mode] != cfg.policy else {}),
                         **(pipeline_record(made[mode]) if mode in made else {}), "clean": mode_clean,
                         "attacks": mode_cells,
                         "worst": worst_case(mode_clean, mode_cells)}
        plot_scorecard_sweep(results[mode], scales, f"{cfg.policy} on {cfg.env}, {mode}", out / f"sweep-{mode}.png")
    timing = {policy: {"cells": {row: got for (p, row), got in zip(timed, late) if p == policy}}
              for policy in dict.fromkeys(p for p, _ in timed)}
    for policy, t in timing.items():  # the timing rows' worst, judged as an attack's: the lowest return
        t["worst"] = worst_case(clean[policy], {row: {1.0: got} for row, got in t["cells"].items()})
        t["clean"] = clean[policy]
    payload = {**stamp("aril scorecard", cfg), "budget": {**vars(budget), "spsa_queries_per_step": budget.spsa_queries},
               "scales": scales, "modes": results,
               **({"timing": {"k": cfg.timing, "policies": timing}} if timing else {})}
    (out / "scorecard.json").write_text(json.dumps(payload, indent=1) + "\n")
    page = out / "scorecard.md"
    page.write_text(scorecard_markdown(payload, cfg.policy, f"{cfg.budget}: {budget.describe()}",
                                       via_of(cfg) == "graph"))
    log(f"[scorecard] {page}: " + "; ".join(
        [f"{mode} worst {SCORECARD_ATTACKS[r['worst']['attack']]} {r['worst']['drop_pct']:+.1f}%"
         for mode, r in results.items()]
        + [f"timing worst {TIMING_ROWS[t['worst']['attack']].format(k=cfg.timing)} {t['worst']['drop_pct']:+.1f}%"
           for t in timing.values()]))
    return page


def run_cells(cfg: ScorecardConfig, budget: Budget, runner: CellRunner, wanted: list[tuple[str, str, float]],
              eps: dict, made: dict, log) -> dict:
    """The figures of each (mode, attack, scale) cell ``wanted``, run together (none: nothing runs)."""
    if not wanted:
        return {}
    plan = [cell(cfg, budget, mode, attack, scale * eps[mode], made.get(mode)) for mode, attack, scale in wanted]
    return dict(zip(wanted, runner.run(plan, log)))


def rows_of(cfg: ScorecardConfig, budget: Budget, attacks: list[str], mode: str, made: BlackBoxAttacks | None
            ) -> list[str]:
    """The attacks scored in ``mode``: those named by ``attacks:=``, else the budget's black-box rows of the mode and
    the white-box ones that apply; never the zoo of an env with no bundled adversary (a new robot)."""
    chosen = [a for a in attacks if cfg.attacks or budget.black_box is None or a in WHITE_BOX
              or a in budget.black_box[mode]]
    return [a for a in chosen if not (a == "zoo" and made is not None and made.zoo is None)]


def via_of(cfg: ScorecardConfig) -> str:
    """Where the cells run: as ``via:=`` says, by default through the graph for an external node, else the engine."""
    return cfg.via or ("graph" if cfg.policy == "external" else "engine")


def check_config(cfg: ScorecardConfig) -> tuple[Budget, list[str], list[str], list[float]]:
    """The budget, modes, attacks and scales, or an error naming the bad argument, before anything runs."""
    chosen = BUDGETS[check_name("budget", cfg.budget, tuple(BUDGETS))]
    budget = dataclasses.replace(chosen, episodes=cfg.episodes or chosen.episodes,
                                 adversary_steps=cfg.adversary_steps or chosen.adversary_steps,
                                 timing_adversary_steps=cfg.timing_steps or chosen.timing_adversary_steps)
    modes = [check_name("mode", m, ATTACKED_MODES) for m in comma_list(cfg.modes)]
    external = cfg.policy == "external"
    if check_name("via", via_of(cfg), VIAS) == "engine" and external:
        raise ValueError("policy:=external is scored through the graph only (your node answers there): drop via:=engine")
    applicable = [a for a in SCORED_ATTACKS if not (external and a in WHITE_BOX)]
    attacks = [check_name("attack", a, applicable) for a in comma_list(cfg.attacks)] if cfg.attacks else applicable
    if external:
        if not cfg.domain.isdigit():
            raise ValueError("policy:=external needs domain:=<the ROS_DOMAIN_ID your node runs in> (start it with "
                             "ROS_DOMAIN_ID=<n> ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), got "
                             f"domain:={cfg.domain or '(unset)'}")
        checked_domain(cfg.domain)
        plugins.load("aril_ros.victims", "ros")  # the ROS side must be installed: says so if it is not
        if cfg.leave_out:
            resolve_policy(cfg.leave_out, cfg.env, modes[0])
    else:
        if cfg.leave_out:
            raise ValueError(f"leave_out:={cfg.leave_out} is for policy:=external (a file scored itself leaves out the "
                             "adversaries trained against it already)")
        resolve_policy(cfg.policy, cfg.env, modes[0])  # a missing or mismatched policy is reported first
    if via_of(cfg) == "graph":
        plugins.load("aril_ros.collectors", "graph")
    resolve_policy(cfg.expert, cfg.env)
    scales = sorted(float(x) for x in comma_list(cfg.scales or budget.scales))
    if 1.0 not in scales or min(scales) <= 0:
        raise ValueError(f"scales:={cfg.scales}: positive multiples of eps, 1 among them (the worst case is judged at "
                         "eps)")
    return budget, modes, attacks, scales


def cell(cfg: ScorecardConfig, budget: Budget, mode: str, attack: str, eps: float,
         made: BlackBoxAttacks | None = None, policy: str = "") -> EvalConfig:
    """A cell of the plan: the episodes of ``policy`` (default: the policy as typed) in ``mode`` under the scored
    ``attack`` at ``eps``: what the black-box pipeline ``made`` for the mode runs as transfer (FGSM^k on its
    surrogate), zoo and aril_a (its adversaries, scaled to that eps: their perturbation times eps / their own eps)
    and aril_a_search (aril_a asking the policy about :data:`~aril_ros.verdict.SEARCH` candidates a step); SPSA^k at
    the budget's queries, fd_fgsm at its iterations (the other attacks keep their own settings: fgsm_k's k is not
    SPSA's)."""
    iterations = {"spsa": {"k": budget.spsa_iterations, "samples": budget.spsa_samples},
                  "fd_fgsm": {"k": budget.fd_iterations}}.get(attack, {})
    kept = made and made.adversary and made.adversary.kept
    files = {"transfer": made and made.surrogate, "zoo": made and made.zoo, "aril_a": kept, SEARCH_ROW: kept,
             DIRECTED_ROW: made and made.directed and made.directed.trained.kept}
    learned = row_attack(attack) == "aril_a"
    return EvalConfig(env=cfg.env, policy=policy or cfg.policy, expert=cfg.expert, mode=mode,
                      attack=row_attack(attack), eps=eps,
                      attack_file=str(files[attack]) if attack in files else "", rescale=learned,
                      search=SEARCH if attack == SEARCH_ROW else 0, episodes=budget.episodes, seed=cfg.seed,
                      horizon=cfg.horizon, **iterations)


def timing_cell(cfg: ScorecardConfig, budget: Budget, policy: str, row: str, file: Path | None = None
                ) -> EvalConfig:
    """A timing row's cell: ``policy`` clean but for the timing attack ``row`` (:data:`aril_ros.timing.TIMING_ROWS`)
    at the scorecard's budget, the most every step, or picked by the timing adversary ``file``."""
    late = {"delay": {"delay": cfg.timing}, "action_delay": {"action_delay": cfg.timing},
            "drop": {"drop": cfg.timing / 10},
            LEARNED_TIMING_ROW: {"drop": cfg.timing / 10, "timing": "learned", "timing_file": str(file)}}[row]
    return dataclasses.replace(cell(cfg, budget, "clean", "none", 0.0, policy=policy), **late)


def timing_adversaries(cfg: ScorecardConfig, budget: Budget, tested: list[str], made: dict, out: Path, log
                       ) -> dict[str, Path]:
    """The learned timing row's adversary per tested policy, trained (or kept from a rerun) black-box: against the
    file, or for an external node against the pipeline's surrogate of it (the sensory one where there are two);
    none for an external node scored without the pipeline, which says so."""
    surrogates = [m.surrogate for mode, m in sorted(made.items(), key=lambda item: item[0] != "sensory") if m.surrogate]
    surrogate = surrogates[0] if surrogates else None
    victims = {policy: policy if cfg.policy != "external" else surrogate for policy in tested}
    if None in victims.values():
        log(f"[scorecard] no learned timing row: it trains against the pipeline's surrogate of an external node, and "
            f"attacks:={cfg.attacks} runs no pipeline ({', '.join(PIPELINE_ATTACKS)})")
    wanted = {policy: AdversaryConfig(env=cfg.env, mode="clean", drop=cfg.timing / 10, victim=str(victim),
                                      expert=cfg.expert, steps=budget.timing_adversary_steps,
                                      out=str(out / f"timing-adversary-{Path(policy).stem}.pt"))
              for policy, victim in victims.items() if victim is not None}
    log(f"[scorecard] the learned timing row: a timing adversary trained {budget.timing_adversary_steps:,} steps "
        f"against {'the surrogate' if cfg.policy == 'external' else 'the policy'} (drops of {cfg.timing}0%)")
    files = ready_adversaries(list(wanted.values()), False, log, cfg.workers, cfg.address)
    return dict(zip(wanted, files))


def runner_of(cfg: ScorecardConfig, out: Path) -> CellRunner:
    """Where the cells run: a file's or a bundled name's as sweep tasks of ``workers`` or on the cluster at
    ``address`` (through the graph each run in a free domain of its node); an external node's one after the other
    here, in the node's domain."""
    logs = out / "logs" if cfg.keep_logs else None
    if cfg.policy == "external":
        return CellRunner(via_of(cfg), workers=1, address="", domain=cfg.domain, logs=logs)
    return CellRunner(via_of(cfg), workers=cfg.workers, address=cfg.address, logs=logs)


def pipelines_for(cfg: ScorecardConfig, modes: list[str], eps: dict, budget: Budget, out: Path, log, rows: dict
                  ) -> dict[str, BlackBoxAttacks]:
    """The black-box pipeline's files for each mode whose ``rows`` need them (:mod:`aril_ros.verdict`: steps 1 to 4
    for the transfer, zoo and ARIL-A rows, step 5 for the directed one), in ``out``; a rerun reuses them. The
    pipelines run side by side, their trainings at once on ``workers`` CPUs (an external node's scorecard starts a Ray
    for them alone: its cells run in this process)."""
    first = [mode for mode in modes if set(rows[mode]) & set(SURROGATE_ATTACKS)]
    directed = [mode for mode in modes if DIRECTED_ROW in rows[mode]]
    if not first and not directed:
        return {}
    log("[scorecard] the black-box pipeline" + (f", {', '.join(first)}: a surrogate, the zoo screened, ARIL-A "
                                                 "trained" if first else "")
        + (f"; {', '.join(directed)}: a directed ARIL-A trained" if directed else "")
        + f" {budget.adversary_steps:,} steps against the policy's answers (eps "
        + ", ".join(f"{eps[m]:g}" for m in modes) + ")")
    scored_on = (cfg.seed, budget.episodes)  # a training's states are judged on the very episodes its row scores
    pipelines = [pipeline(victim_of(cfg.policy, cfg.env, mode), cfg.env, mode, eps[mode], cfg.expert,
                          budget.adversary_steps, out, scored_on, cfg.domain, log, cfg.horizon,
                          policy_in(cfg.leave_out, cfg.env, mode) if cfg.leave_out else "") for mode in first]
    pipelines += [directed_pipeline(victim_of(cfg.policy, cfg.env, mode), cfg.env, mode, eps[mode], cfg.expert,
                                    budget.adversary_steps, out, scored_on, cfg.domain, log, cfg.horizon,
                                    policy_in(cfg.leave_out, cfg.env, mode) if cfg.leave_out else "")
                  for mode in directed]
    with session(cfg.workers, cfg.address) if cfg.policy == "external" else nullcontext():
        made = run_pipelines(pipelines, log, cfg.workers, cfg.address)
    attacks = dict(zip(first, made))
    for mode, steered in zip(directed, made[len(first):]):
        attacks[mode] = dataclasses.replace(attacks.get(mode, BlackBoxAttacks()), directed=steered)
    return attacks


def pipeline_record(made: BlackBoxAttacks) -> dict:
    """What scorecard.json keeps of a mode's pipeline: its files, the surrogate's fidelity and questions, the zoo,
    ARIL-A's and the directed ARIL-A's training steps and questions (of what the mode's rows needed)."""
    record = {}
    if made.surrogate:
        made_by = load_policy(made.surrogate).meta.provenance
        record |= {"surrogate": relative(made.surrogate), "surrogate_fidelity": made_by["fidelity"],
                   "surrogate_queries": made_by["queries"], "zoo": made.zoo and relative(made.zoo),
                   "zoo_screened": made.screened, **training_record("adversary", made.adversary)}
    if made.directed:
        steered = made.directed
        record |= {**training_record("directed", steered.trained),
                   "directed_zoo": steered.zoo and relative(steered.zoo), "directed_zoo_screened": steered.screened,
                   "directed_zoo_queries": steered.queries}
    return record


def training_record(name: str, trained: Trained) -> dict:
    """What scorecard.json keeps of a pipeline training ``name`` (adversary, directed): the state its row used, the
    training's steps and questions, the step of the state kept, and its states' judging on the scored episodes (each
    state's return in each)."""
    end = load_adversary(trained.end).meta["provenance"]
    return {name: relative(trained.kept), f"{name}_steps": end["steps"], f"{name}_queries": end["queries"],
            f"{name}_kept_steps": load_adversary(trained.kept).meta["provenance"]["steps"],
            f"{name}_states_screened": trained.screened, f"{name}_states_queries": trained.queries,
            f"{name}_states_returns": trained.returns}


def victim_of(policy: str, env_id: str, mode: str) -> str:
    """What the adversary trainer is told to attack (and its file records): an external node through ROS (``ros``),
    else the policy in ``mode`` (:func:`policy_in`)."""
    return "ros" if policy == "external" else policy_in(policy, env_id, mode)


def policy_in(policy: str, env_id: str, mode: str) -> str:
    """The policy under test in attacked ``mode``, as a run that may be in another mode (the clean one, the
    adversary trainer's) must be told it: the policy as typed, and for a bundled name trained per mode, which such a
    run could not resolve, its file for ``mode``, relative to here when it can be."""
    return relative(bundled_file(policy, env_id, mode)) if policy in PER_MODE_POLICIES else policy


def worst_case(clean: dict, cells: dict) -> dict:
    """The attack with the lowest return at scale 1 (the tables' rule), with its paired drop."""
    attack = worst_attack({a: {"mean": sweep[1.0]["mean_return"]} for a, sweep in cells.items()}, among=tuple(cells))
    return {"attack": attack, "return": cells[attack][1.0]["mean_return"], **paired_drop(clean, cells[attack][1.0])}
