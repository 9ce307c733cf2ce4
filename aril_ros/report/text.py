"""The markdown of ``docs/results.md``: built only from the figures ``aril report`` computed (its
``report.json``), so regenerating the report regenerates every sentence that quotes a number; and a scorecard's
page, from its ``scorecard.json`` alike."""
from __future__ import annotations

from pathlib import Path

from .. import timing_table  # the module, not its names: it imports report.stats, so it may be importing us
from ..envs import layout_of
from ..registry import ATTACKS, DEFENSES, MODES, PAPER_DEFENSES, SCORECARD_ATTACKS, TABLE_SEARCH, WHITE_BOX
from ..timing import TIMING_ROWS
from .compute import compute_lines
from .paper import BLACK_BOX_ROWS, PAPER_CLEAN, PAPER_OBS_DIM, PAPER_OVERALL, TABLE_ROWS
from .stats import episodes_to_pin, paired_drop, worst_attack
from .tables import DAGGER_ATTACKS, PAPER_ATTACKS


def _drop(cell: dict | None, reference: dict | None) -> float | None:
    if not cell or not reference or not reference["mean"]:
        return None
    return 100.0 * (cell["mean"] / reference["mean"] - 1.0)


def _list(items: list[str]) -> str:
    return ", ".join(items) if items else "none"


def comparison(payload: dict, cells: dict) -> list[str]:
    """Where our attack is stronger or weaker and our defenses hold more or less than the paper's."""
    lines = []
    for mode, by_env in cells.items():
        strongest, weaker, most_robust, aril_rank, black_box = [], [], [], [], []
        for env, row in by_env.items():
            clean = row.get(("dagger", "none"))
            attacks = {a: _drop(row.get(("dagger", a)), clean) for a in DAGGER_ATTACKS}
            attacks = {a: d for a, d in attacks.items() if d is not None}
            gradient = [a for a in WHITE_BOX if a in attacks]
            if "aril_a" in attacks and gradient:
                best_other = min(gradient, key=lambda a: attacks[a])
                target = strongest if attacks["aril_a"] <= attacks[best_other] else weaker
                target.append(f"{env} ({attacks['aril_a']:+.1f}% vs {ATTACKS[best_other]} "
                              f"{attacks[best_other]:+.1f}%)")
            asking = [a for a in ("aril_a", *BLACK_BOX_ROWS) if a in attacks]  # the black-box rows evaluated
            if asking and "fgsm_k" in attacks:
                best = min(asking, key=lambda a: attacks[a])
                black_box.append((attacks[best] <= attacks["fgsm_k"], f"{env} {SCORECARD_ATTACKS[best]} "
                                  f"{attacks[best]:+.1f}% vs {attacks['fgsm_k']:+.1f}%"))
            defenses = {d: row.get((d, "worst")) for d in PAPER_DEFENSES if d != "dagger"}
            defenses = {d: c for d, c in defenses.items() if c}
            if clean:  # DAgger's own worst case is the undefended baseline
                worst = worst_attack({a: row.get(("dagger", a)) for a in PAPER_ATTACKS}, among=PAPER_ATTACKS)
                if worst:
                    defenses["dagger"] = row[("dagger", worst)]
            ranked = sorted(defenses, key=lambda d: -defenses[d]["mean"])
            if ranked:
                most_robust.append(f"{env}: {DEFENSES[ranked[0]]} ({defenses[ranked[0]]['mean']:.0f})")
            if "aril" in ranked:
                aril_rank.append(f"{env}: {ranked.index('aril') + 1} of {len(ranked)}")
        overall = payload["overall_drop"].get(mode, {})
        aril_overall = overall.get("aril worst")
        side_by_side = [f"{SCORECARD_ATTACKS[a] if d == 'dagger' else DEFENSES[d]} {overall[f'{d} {a}']:+.1f}% "
                        f"({'—' if (p := PAPER_OVERALL[mode].get((d, a))) is None else f'{p:+.1f}%'})"
                        for d, a in TABLE_ROWS[1:] if overall.get(f"{d} {a}") is not None]
        against_white_box = (
            f"The strongest black-box attack (ARIL-A, ARIL-A + search, directed ARIL-A or FGSM^k on a surrogate) takes "
            f"at least as much "
            f"as white-box FGSM^k in {sum(ok for ok, _ in black_box)} of {len(black_box)} envs: "
            f"{_list([text for _, text in black_box])}. " if black_box else "")
        lines += [f"**{mode.capitalize()} attacks.** ARIL-A is the strongest attack on DAgger in {_list(strongest)}; "
                  f"weaker than the best gradient attack in {_list(weaker)} (the paper: strongest in all three). "
                  f"{against_white_box}"
                  f"Most robust defense under its worst attack: {_list(most_robust)}. ARIL's rank: {_list(aril_rank)} "
                  f"(the paper: first everywhere). ARIL's overall drop: "
                  f"{'—' if aril_overall is None else f'{aril_overall:+.1f}%'} "
                  f"(the paper: {PAPER_OVERALL[mode][('aril', 'worst')]:+.1f}%). Overall drops, ours (the paper's): "
                  f"{_list(side_by_side)}.", ""]
    envs = payload["envs"]
    clean = {env: next(iter(cells.values()))[env].get(("dagger", "none")) for env in envs}
    lines += ["**Likely reasons.**", "",
              "- *Expert and learner strength.* Our clean DAgger learners score "
              + ", ".join(f"{env} {clean[env]['mean']:.0f} (paper {PAPER_CLEAN[env]})" for env in envs if clean[env])
              + ". Stronger, faster gaits visit a narrower band of states, so the same perturbation takes the "
                "learner further outside its data; drops in % are not comparable across such different baselines.",
              "- *eps.* Ours are calibrated on our DAgger learners by the paper's rule (the largest eps whose FGSM "
              "drop stays within 40%): " + ", ".join(f"{k} {v:g}" for k, v in payload["eps"].items())
              + ". The paper's per-env values are in its supplement, which we do not have; a larger sensory eps "
                "(Swimmer 0.3) makes every defense's worst case harsher.",
              "- *Env versions.* v5 on MuJoCo 3 against v2 on mujoco-py; observation sizes "
              + ", ".join(f"{env} {layout_of(env).obs_dim} (v2 {PAPER_OBS_DIM[env]})" for env in envs)
              + (". Ant's contact-force entries and termination rules differ, so Ant's figures carry the least "
                 "comparison weight (its clean DAgger return also has the widest spread: episodes where it falls)."
                 if "Ant-v5" in envs else "."),
              "- *ARIL's adversary budget.* " + _budgets(payload["aril_rounds"])
              + " (each run's under ARIL's rounds, below). The evaluation's ARIL-A against the finished learner "
                "trains for 1,000,000 steps from scratch. A round adversary weaker than that lets the learner beat "
                "each f_t and stay fragile against a stronger one; warm-starting each round's adversary from the "
                "last, or keeping the strongest of several fresh ones, keeps up (`results/aril_a_tuning.md`). The "
                "paper does not give its per-round budget.",
              "- *Statistics.* " + (f"{len(payload['seeds'])} training seeds per defense: the intervals are over the "
                                    "seeds' means (Student-t), so they bound seed-to-seed variation and are wide with "
                                    "this few seeds; each seed's episodes are in the JSON."
                                    if len(payload["seeds"]) > 1 else
                                    "One training seed (the quick budget): the intervals cover episode noise only, "
                                    "not seed-to-seed variation; `budget:=full` trains 3 seeds per defense."), ""]
    return lines


def _budgets(curves: dict) -> str:
    """Each way ARIL's runs made their round adversaries, followed by the runs that did (by env and mode: a run's
    seeds share its settings, and naming each of them would repeat the table of rounds)."""
    runs = {}
    for name, curve in curves.items():
        runs.setdefault(_round_adversaries(curve), {})[name.split(" seed ")[0]] = None
    return "; ".join(f"{budget}: {_list(list(names))}" for budget, names in runs.items()) or "none"


def _round_adversaries(curve: dict) -> str:
    """How an ARIL run made each round's f_t (its settings: an older file reads as the defaults, one per round)."""
    seeds = curve["adversary_seeds"]
    return f"{curve['adversary_steps']:,} steps per round, " + (
        "warm-started from the previous round's adversary" if curve["warm_start"] else
        "fresh each round" + (f", the strongest of {seeds}" if seeds > 1 else ""))


def performance(benchmarks: dict) -> list[str]:
    if not benchmarks:
        return ["Not run (`perf:=false`)."]
    lines = []
    engine, graph, adversary = (benchmarks.get(name, {}) for name in ("engine", "graph", "adversary"))
    raw = engine.get("raw env.step")
    if raw:
        lines += [f"{engine.get('env')}, steps/s and ratio to raw MuJoCo (`env.step`, {raw:.0f} steps/s), "
                  "one torch thread:",
                  "", "| mode | in-process engine (32 envs) | vs raw | ROS graph (5 processes) | vs raw | "
                      "graph + MCAP record | vs raw |", "|---|---|---|---|---|---|---|"]
        for mode in MODES:
            e, g = engine.get(f"engine {mode}"), graph.get(mode, {})
            row = [e, g.get("graph"), g.get("graph+record")]
            lines.append(f"| {mode} | " + " | ".join("—" if v is None else f"{v:.0f} | {v / raw:.2f}" for v in row)
                         + " |")
        bare = {mode: graph[mode]["bare chain"] for mode in MODES if "bare chain" in graph.get(mode, {})}
        if bare:
            lines += ["", "Bare 4-process rclpy chain (the same roles, no orchestrator, recorder or guards), measured "
                          "beside each mode: " + ", ".join(
                              f"{mode} {v:.0f} steps/s (graph {graph[mode]['graph / bare']:.2f}x, with record "
                              f"{graph[mode]['graph+record / bare']:.2f}x)" for mode, v in bare.items()) + "."]
        lines.append("")
    if adversary and "error" not in adversary:
        base = adversary.get("SB3 PPO (1 env)")
        lines += [f"Adversary training, env steps/s ({adversary.get('env')}, one torch thread), ratio to "
                  "stable-baselines3 PPO on one env:", "", "| trainer | steps/s | ratio |", "|---|---|---|"]
        lines += [f"| {k} | {v:.0f} | {v / base:.2f}x |" for k, v in adversary.items()
                  if isinstance(v, float) and base]
        lines.append("")
    for name, figures in benchmarks.items():
        if "error" in figures:
            lines.append(f"- {name} benchmark failed: {figures['error']} (`{figures['command']}`)")
    lines.append("Commands: " + "; ".join(f"`{f['command']}`" for f in benchmarks.values()) + ".")
    return lines


def _more_seeds(payload: dict) -> str:
    """Where the report trained more seeds than ``seeds:=`` (``more_seeds:=``, the cells those could not separate)."""
    more = {cell: seeds for cell, seeds in payload.get("seeds_per_cell", {}).items() if seeds != payload["seeds"]}
    if not more:
        return ""
    added = sorted({s for seeds in more.values() for s in seeds} - set(payload["seeds"]))
    return (f", and {', '.join(map(str, added))} too where those could not separate a cell's top two defenses: "
            + _list(list(more)))


def _cache_note(payload: dict) -> str:
    """The run's minutes cover only what it computed: say so when evaluations came from an earlier run's cache."""
    counts = payload["evaluations_run"]
    if not counts["cached"]:
        return ""
    return (f"; {counts['run']} of {counts['run'] + counts['cached']} distinct evaluations run here, the rest read "
            "from the cache of earlier runs")


def _machines_note(payload: dict) -> str:
    """Which CPU models the evaluations ran on: a report resumed on other machines, or run on a cluster, can mix
    them, and each gives its own floating-point episodes."""
    cpus = payload["evaluated_on"]
    if len(cpus) == 1:
        return f"evaluated on {next(iter(cpus))}"
    return "evaluated on " + ", ".join(f"{cpu} ({n} evaluations)" for cpu, n in cpus.items())


def leads_lines(payload: dict) -> list[str]:
    """Per env and mode, the two defenses that keep the most under their worst attack and how far the first leads,
    seed by seed; and, plainly, the cells where the table cannot tell them apart."""
    lines = ["Per env and mode, the two defenses that keep the most under their worst attack, and the first's lead: "
             "the difference of the two returns training seed by training seed (each a mean over the same "
             "episodes), its mean and 95% Student-t interval over the seeds. Where the interval holds 0 the table "
             "cannot say which of the two keeps more.", "",
             "| env, mode | first | second | lead [95% over seeds] | seeds | separated |", "|---|---|---|---|---|---|"]
    unsettled = []
    for cell, lead in payload.get("top_two", {}).items():
        if lead is None:
            continue
        low, high = lead["difference"] - lead["ci95"], lead["difference"] + lead["ci95"]
        first, second = DEFENSES[lead["first"]], DEFENSES[lead["second"]]
        lines.append(f"| {cell} | {first} ({lead['first_mean']:.0f}) | {second} ({lead['second_mean']:.0f}) | "
                     f"{lead['difference']:+.0f} [{low:+.0f}, {high:+.0f}] | {len(lead['seeds'])} | "
                     f"{'yes' if lead['separated'] else '**no**'} |")
        if not lead["separated"]:
            unsettled.append(f"{cell} ({first} or {second})")
    lines += ["", f"The table cannot separate the top two in {len(unsettled)} of "
                  f"{sum(lead is not None for lead in payload.get('top_two', {}).values())} cells"
                  + (f": {_list(unsettled)}." if unsettled else "."), ""]
    return lines


def report_markdown(payload: dict, tables: dict, cells: dict, overall: dict, out: Path, gifs: list[Path]) -> str:
    figures = out.with_suffix("").name  # links relative to the report
    seeds = payload["seeds"]
    lines = [
        "# Results: attacks and defenses on MuJoCo (aril_ros)", "",
        f"Regenerated by `{payload['command']}` at git revision `{payload['git_revision']}` on {payload['created']} "
        f"({payload['cores']} cores, {payload['seconds'] / 60:.0f} min{_cache_note(payload)}) with "
        + ", ".join(f"{name} {version}" for name, version in payload["versions"].items() if name != "cpu")
        + f"; {_machines_note(payload)} (another MuJoCo, gymnasium or CPU model gives other returns from the same "
        "files). Every figure below "
        f"is in [`{figures}/report.json`]({figures}/report.json): each evaluation's arguments and per-episode returns, "
        "and the sha256 digest of every policy and adversary file used (listed at the end with the command that "
        "made it).", "",
        "## Protocol", "",
        f"- Envs: {', '.join(payload['envs'])} (gymnasium v5, horizon 1000); the paper used the v2 envs.",
        f"- Budget `{payload['budget']}`: training seeds {', '.join(map(str, seeds))} per defense (seed 0 is the "
        "bundled policy)" + _more_seeds(payload) + "; deterministic policies, evaluation env seeds "
        + payload["episode_seeds"] + ".",
        "- Each cell: mean ± the half-width of a 95% Student-t interval (over the training seeds' means when there "
        "are several, else over the episodes); in brackets the drop from clean DAgger and, for a defense, the attack "
        "that hurt it most among random, FGSM, FGSM^k (10 steps), SPSA^k (black-box, 5 steps) and an ARIL-A trained "
        "against that very defense. DAgger also meets the black-box verdict pipeline's strongest attacks, rows the "
        f"paper has not: FGSM^k on a surrogate fitted to its answers, its ARIL-A with query-time search "
        f"({TABLE_SEARCH} candidates a step), and a directed ARIL-A (a direction in its action space, turned into a "
        "perturbation by finite differences of its answers: PA-AD's director and actor, black-box).",
        "- eps per env and mode: the calibrated one (`aril_ros/data/eps_calibration.json`, made by "
        "`aril calibrate-eps`).", *compute_lines(payload["compute"]), "",
    ]
    for mode in tables:
        number = 1 if mode == "sensory" else 2
        lines += [f"## Table {number}: {mode} attacks", "", *tables[mode], ""]
    lines += ["## Which defense leads", "", *leads_lines(payload)]
    lines += ["## Comparison with the paper", "", *comparison(payload, cells)]
    lines += ["## eps sweeps", "",
              "Return vs eps (0 = clean, the dotted line = the calibrated eps) for each defense under each attack. "
              "ARIL-A's points away from the calibrated eps scale the perturbation of the adversary trained at it.", ""]
    for mode in payload["modes"]:
        for env in payload["envs"]:
            lines += [f"![{env} {mode}]({figures}/sweep-{env}-{mode}.png)", ""]
    lines += ["## ARIL's rounds", "",
              "Clean return and return under that round's adversary f_t, per round (round 0: the expert's "
              "demonstrations); the dotted line marks the returned policy (the best under its own adversary).", "",
              f"![ARIL rounds]({figures}/aril-rounds.png)", "",
              "| run | rounds | returned | round adversaries |", "|---|---|---|---|"]
    lines += [f"| {name} | {len(c['round']) - 1} | {c['selected']} | {_round_adversaries(c)} |"
              for name, c in payload["aril_rounds"].items()]
    lines += timing_section(out)
    lines += ["", "## Performance", "", *performance(payload["benchmarks"]), ""]
    lines += ["## Seeing an attack", ""]
    if gifs:
        lines += ["Left to right: DAgger clean, DAgger under the ARIL-A trained against it, ARIL under the ARIL-A "
                  "trained against it (`aril render`, MuJoCo offscreen on the CPU).", ""]
        lines += [f"![{Path(g).stem}]({figures}/{Path(g).name})" for g in gifs]
    else:
        lines.append("Not rendered in this run (`render:=true` renders; `aril render` does one env and mode).")
    lines += ["", "## Files", "", "| file | sha256 (12) |", "|---|---|"]
    lines += [f"| `{f}` | {d} |" for f, d in sorted(payload["files"].items())]
    if payload["missing"]:
        lines += ["", "Could not be produced:", ""]
        lines += [f"- {k}: {v}" for k, v in payload["missing"].items()]
    lines += ["", "Each file's provenance (training command, git revision, seeds) is inside it: "
                  "`python -c \"from aril_ros.policy import load_weights; print(load_weights('FILE')[0]"
                  "['provenance'])\"` (add `, 'adversary'` for an adversary).", ""]
    return "\n".join(lines)


def timing_section(out: Path) -> list[str]:
    """The report's timing section (the report at ``out``), from the table ``aril timing-table`` keeps where it writes
    it by default; nothing when there is none."""
    timing = timing_table.report_lines(Path(timing_table.TimingTableConfig().out).with_suffix(".json"), out)
    if not timing:
        return []
    return ["", "## Timing attacks", "",
            "Observations late or dropped and actions late, each alone, against the defenses above and against "
            "defenses trained with a timing budget in their loop (`aril timing-table`, "
            "[attacks and defenses](attacks-defenses.md#timing-attacks)); made apart from this report's run.", "",
            *timing]


HOW_ATTACKS_ASK = (
    "How each attack uses the policy (none takes its weights but the white-box ones, which a file alone allows; "
    "the tables' questions per step are those each attack put to it, counted as they were asked, besides the "
    "step's own action):",
    "- random: not at all;",
    "- SPSA^k: asks it about the points of its gradient estimate;",
    "- FGSM^k on a surrogate (transfer): FGSM^k on a copy of the policy fitted to its answers (the surrogate: "
    "its questions and held-out fidelity below); it asks the policy nothing while it attacks;",
    "- ARIL-A from the zoo: the bundled adversary (none trained against this very file) that took the most return "
    "from the surrogate on screening episodes; one question per step when the policy's action is an input of it;",
    "- ARIL-A: trained from the zoo's adversary against the policy's answers (two questions a training step: its "
    "action on the true state and on the perturbed one; the count below); of the states its training kept, the one "
    "that took the most return on these very episodes; asks as the zoo's;",
    "- ARIL-A + search: ARIL-A's choice and 8 of its draws, the policy asked about all 9 each step besides "
    "ARIL-A's own question, the most damaging applied;",
    "- ARIL-A, directed: trained against the policy's answers (the count below) from the bundled directed ARIL-A "
    "that took the most return from it on screening episodes (none trained against this very file); it picks a "
    "direction for the policy's action, asks the policy about two points per perturbed entry each step (its action's "
    "slope along each) besides its own question, and takes the corner of the box that moves the action furthest "
    "along that direction; its state chosen as ARIL-A's;",
    "- FGSM, FGSM^k (a file only): white-box, the gradient of the file itself.")


def pipeline_lines(mode_result: dict) -> list[str]:
    """The page's lines on a mode's black-box pipeline: the surrogate's questions and fidelity, the zoo's choice,
    ARIL-A's training, the directed ARIL-A's (of what the mode's rows needed)."""
    directed = ([f"Directed ARIL-A: `{mode_result['directed']}`, {kept_state(mode_result, 'directed')}, "
                 + (f"from `{mode_result['directed_zoo']}`, the strongest of "
                    f"{len(mode_result['directed_zoo_screened'])} against the policy "
                    f"({mode_result['directed_zoo_queries']:,} questions)." if mode_result["directed_zoo"]
                    else "from fresh weights (no bundled directed ARIL-A of another policy)."), ""]
                if "directed" in mode_result else [])
    if "surrogate" not in mode_result:
        return directed
    fidelity = mode_result["surrogate_fidelity"]
    return [f"Surrogate `{mode_result['surrogate']}`: {mode_result['surrogate_queries']:,} questions to the policy, "
            f"held-out error {fidelity['mse']:.4f} (R^2 {fidelity['r2']:.4f}, inside the ±eps box "
            f"{fidelity['local_r2']:.4f}); "
            + (f"zoo: `{mode_result['zoo']}`, the strongest of {len(mode_result['zoo_screened'])} against the "
               "surrogate; " if mode_result["zoo"] else "no bundled adversary for a zoo; ")
            + f"ARIL-A: `{mode_result['adversary']}`, {kept_state(mode_result, 'adversary')}.", "", *directed]


def kept_state(mode_result: dict, name: str) -> str:
    """How a pipeline training ``name`` (adversary, directed) went: its steps and questions, and which of its states
    the row used (the one that took the most return from the policy on the scored episodes)."""
    states = len(mode_result[f"{name}_states_screened"])
    return (f"the state after {mode_result[f'{name}_kept_steps']:,} of {mode_result[f'{name}_steps']:,} steps trained "
            f"against the policy ({mode_result[f'{name}_queries']:,} questions), the strongest of {states} "
            f"state{'s' if states != 1 else ''} against the policy on these episodes "
            f"({mode_result[f'{name}_states_queries']:,} questions)")


def too_few_episodes(worst: dict, episodes: int) -> list[str]:
    """A warning when the worst case's interval is as wide as the drop it reports (Ant's clean episodes swing from a
    dozen steps to the horizon): the verdict needs more episodes, about as many as it names; else nothing."""
    wanted = episodes_to_pin(worst, episodes)
    if wanted is None:
        return []
    return [f"*The interval is as wide as the drop: {episodes} episodes do not pin this verdict down; score more "
            f"(`episodes:={wanted}` would likely narrow it below the drop).*", ""]


def scorecard_markdown(card: dict, policy: str, budget: str, through_graph: bool) -> str:
    """A scorecard's page (``scorecard.md``) from what its ``scorecard.json`` holds (``card``, its scales and the
    sweeps' keys floats), the policy as typed, the budget as a sentence, and whether its cells were runs of the
    graph."""
    settings, episodes = card["settings"], card["budget"]["episodes"]
    lines = [f"# Scorecard: {policy} on {settings['env']}", "",
             f"`{card['command']}` (revision {card['git_revision']}, {card['created']}). Budget {budget}; env seeds "
             f"{settings['seed']}..{settings['seed'] + episodes - 1} in every cell (paired), each "
             f"{'a run of the ROS 2 graph' if through_graph else 'on the engine'}. Drop: mean of the per-episode "
             "differences from clean, in % of the clean return, with a Student-t 95% interval. Every episode is in "
             "`scorecard.json`." + (" Through the graph the eps sweep (each of its cells a run too) is each mode's "
                                    "worst attack's alone: – marks a cell not run."
                                    if through_graph and len(card["scales"]) > 1 else ""),
             "", *HOW_ATTACKS_ASK, ""]
    for mode, r in card["modes"].items():
        worst = r["worst"]
        lines += [f"## {mode}, eps {r['eps']:g} ({r['eps_source']})", "",
                  # a name trained per mode is another policy in each mode: the file of this one, clean row included
                  *([f"The {policy} policy trained against {mode}: `{r['policy']}`.", ""] if "policy" in r else []),
                  *pipeline_lines(r),
                  f"**Worst case: {SCORECARD_ATTACKS[worst['attack']]}, return {worst['return']:.1f}, "
                  f"{worst['drop_pct']:+.1f}% [{worst['ci95_pct'][0]:+.1f}, {worst['ci95_pct'][1]:+.1f}]** "
                  f"(clean {r['clean']['mean_return']:.1f}).", "",
                  *too_few_episodes(worst, episodes),
                  "| attack | return at eps | drop at eps [95%] | expert loss | questions per step | return at " +
                  ", ".join(f"{s:g}x" for s in card["scales"]) + " eps |", "|---|---|---|---|---|---|",
                  f"| clean | {r['clean']['mean_return']:.1f} | | {r['clean']['mean_expert_loss']:.4f} | | |"]
        for attack, sweep in r["attacks"].items():
            at = sweep[1.0]
            drop = paired_drop(r["clean"], at)
            lines.append(f"| {SCORECARD_ATTACKS[attack]} | {at['mean_return']:.1f} | {drop['drop_pct']:+.1f}% "
                         f"[{drop['ci95_pct'][0]:+.1f}, {drop['ci95_pct'][1]:+.1f}] | {at['mean_expert_loss']:.4f} | "
                         f"{'gradients' if attack in WHITE_BOX else format(at['queries_per_step'], 'g')} | "
                         + ", ".join(f"{sweep[s]['mean_return']:.0f}" if s in sweep else "–" for s in card["scales"])
                         + " |")
        lines += ["", f"![return against eps, {mode}](sweep-{mode}.png)", ""]
    return "\n".join(lines + timing_lines(card, policy))


def timing_lines(card: dict, policy: str) -> list[str]:
    """The page's timing section (``card["timing"]``; none: nothing): per policy file the clean row and each timing
    row's return and drop, its worst first."""
    if "timing" not in card:
        return []
    k = card["timing"]["k"]
    lines = [f"## Timing, {k} step(s)", "",
             "The policy clean but for its timing: what it sees or does arrives late, the most every step (aril_ros's "
             "docs/attacks-defenses.md, Timing attacks). Drops from its clean return, on the same episodes.", ""]
    for file, t in card["timing"]["policies"].items():
        worst = t["worst"]
        lines += [*([f"`{file}`:", ""] if len(card["timing"]["policies"]) > 1 else []),
                  f"**Worst: {TIMING_ROWS[worst['attack']].format(k=k)}, return {worst['return']:.1f}, "
                  f"{worst['drop_pct']:+.1f}% [{worst['ci95_pct'][0]:+.1f}, {worst['ci95_pct'][1]:+.1f}]**.", "",
                  "| timing | return | drop [95%] | expert loss |", "|---|---|---|---|"]
        for row, got in t["cells"].items():
            drop = paired_drop(t["clean"], got)
            lines.append(f"| {TIMING_ROWS[row].format(k=k)} | {got['mean_return']:.1f} | {drop['drop_pct']:+.1f}% "
                         f"[{drop['ci95_pct'][0]:+.1f}, {drop['ci95_pct'][1]:+.1f}] | {got['mean_expert_loss']:.4f} |")
        lines.append("")
    return lines
