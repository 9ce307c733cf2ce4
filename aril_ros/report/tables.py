"""The report's tables in the paper's layout: each row's cell (from :mod:`.stats`) per env, our
figure beside the paper's, and the overall drop per row."""
from __future__ import annotations

from ..registry import ATTACKS, DEFENSES, SCORECARD_ATTACKS
from .paper import BLACK_BOX_ROWS, PAPER, PAPER_ENV, PAPER_OVERALL, TABLE_ROWS
from .stats import paired_difference, summarise, worst_attack

ROBUST_ROWS = tuple(d for d, a in TABLE_ROWS if a == "worst")
"""The defenses the tables rank by their worst attack (the Robust IL rows)."""
DAGGER_ATTACKS = tuple(a for d, a in TABLE_ROWS if d == "dagger" and a != "none")
"""The attacks on DAgger the tables show as rows of their own (the Adversary rows)."""
PAPER_ATTACKS = tuple(a for a in DAGGER_ATTACKS if a not in BLACK_BOX_ROWS)
"""The paper's Adversary rows: DAgger's worst case among them is the undefended baseline, as in the paper."""


def table_cells(evals: dict, env: str, mode: str) -> dict:
    """Each table row's cell for one env and mode (None when not evaluated); a defense's ``worst`` row is
    its cell under its worst attack, with ``attack`` and its ``clean`` mean beside."""
    per_attack: dict[str, dict[str, dict]] = {}
    for (e, m, defense, attack, scale), per_seed in evals.items():
        if e == env and m == mode and scale in (0.0, 1.0):
            per_attack.setdefault(defense, {})[attack] = summarise(per_seed)
    cells = {}
    for defense, attack in TABLE_ROWS:
        own = per_attack.get(defense, {})
        if attack != "worst":
            cells[(defense, attack)] = own.get(attack)
            continue
        worst = worst_attack(own)
        cells[(defense, attack)] = None if worst is None else {**own[worst], "attack": worst,
                                                               "clean": (own.get("none") or {}).get("mean")}
    return cells


def _fmt_paper(mode: str, row: tuple, env: str) -> str:
    figure = PAPER[mode].get(row, {}).get(env)
    if figure is None:
        return "—"
    return f"{figure[0]:,}" + ("" if row == ("dagger", "none") else f" ({figure[1]:+.1f}%)")


def row_label(row: tuple) -> str:
    defense, attack = row
    if defense == "dagger":
        return "DAgger, clean" if attack == "none" else f"{SCORECARD_ATTACKS[attack]} (on DAgger)"
    return DEFENSES[defense]


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
                    text += f" ({drop:+.1f}%{', ' + ATTACKS[cell['attack']] if 'attack' in cell else ''})"
                parts.append(text)
            parts.append(_fmt_paper(mode, row, env))
        overall[row] = sum(drops) / len(drops) if len(drops) == len(envs) else None
        paper_overall = PAPER_OVERALL[mode].get(row)
        lines.append(f"| {row_label(row)} | " + " | ".join(parts)
                     + f" | {'—' if overall[row] is None else f'{overall[row]:+.1f}%'}"
                     + f" | {'—' if paper_overall is None else f'{paper_overall:+.1f}%'} |")
    return lines, overall


def make_tables(evals: dict, envs: list[str], modes: list[str], eps: dict, missing: dict) -> tuple[dict, dict, dict]:
    """Per mode: each env's cells, the table's markdown lines and each row's overall drop."""
    cells = {mode: {env: table_cells(evals, env, mode) for env in envs} for mode in modes}
    tables, overall = {}, {}
    for mode in modes:
        tables[mode], overall[mode] = table_markdown(mode, envs, cells[mode], {e: eps[e, mode] for e in envs}, missing)
    return cells, tables, overall


def top_two(cells: dict, per_seed: dict[tuple, float]) -> dict | None:
    """One env and mode's two defenses that keep the most under their worst attack (``cells``: the table's), and
    the first's lead over the second seed by seed (:func:`.stats.paired_difference`); ``per_seed`` holds each
    (defense, attack, training seed)'s mean return. None with fewer than two defenses evaluated."""
    ranked = sorted((d for d in ROBUST_ROWS if cells.get((d, "worst"))), key=lambda d: -cells[(d, "worst")]["mean"])
    if len(ranked) < 2:
        return None
    first, second = ranked[:2]

    def seeds_of(defense: str) -> dict[int, float]:
        attack = cells[(defense, "worst")]["attack"]
        return {seed: mean for (d, a, seed), mean in per_seed.items() if (d, a) == (defense, attack)}

    return {"first": first, "second": second, "first_mean": cells[(first, "worst")]["mean"],
            "second_mean": cells[(second, "worst")]["mean"], **paired_difference(seeds_of(first), seeds_of(second))}
