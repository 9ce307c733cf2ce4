"""The one producer of table cells: per-episode returns (grouped by training seed) in, a cell out;
the one rule for a defense's worst attack; and the paired drop of a scorecard's cell from its clean cell.
``aril attack-table`` / ``defense-table`` print a cell's mean ± std, ``aril report`` its mean ± ci95: the same
cell either way."""
from __future__ import annotations

import math

import numpy as np

from ..registry import THREATS

# Student's t, two-sided 95%, by degrees of freedom (the interval of a mean over seeds or episodes)
T95 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262, 10: 2.228,
       15: 2.131, 20: 2.086, 30: 2.042, 40: 2.021, 60: 2.000, 120: 1.980}


def t95(df: int) -> float:
    """The nearest tabled t at or below ``df`` degrees of freedom: a slightly wider interval, never a narrower one."""
    return T95[max(k for k in T95 if k <= max(df, 1))]


def half_width(units: np.ndarray) -> float:
    """Half-width of a Student-t 95% interval of the mean of ``units`` (nan for fewer than two)."""
    return t95(len(units) - 1) * units.std(ddof=1) / math.sqrt(len(units)) if len(units) > 1 else float("nan")


def summarise(per_seed: list[list[float]]) -> dict:
    """A table cell from the per-episode returns of each training seed: ``mean`` (of the seed means),
    ``std`` (over all episodes, as ``aril eval`` prints it), ``ci95`` (half-width of a Student-t 95%
    interval: over the seed means when there are several seeds, since seed-to-seed variation is what a
    reader wants bounded, else over the episodes), ``median``, ``seeds``, ``episodes`` (per seed), ``ci_over``."""
    means = np.array([np.mean(r) for r in per_seed])
    units = means if len(per_seed) > 1 else np.asarray(per_seed[0], dtype=float)
    half = half_width(units)
    episodes = np.concatenate([np.asarray(r, dtype=float) for r in per_seed])
    return {"mean": float(means.mean()), "std": float(episodes.std()), "ci95": float(half),
            "median": float(np.median(episodes)), "seeds": len(per_seed), "episodes": len(per_seed[0]),
            "ci_over": "seeds" if len(per_seed) > 1 else "episodes"}


def worst_attack(cells: dict, among=THREATS) -> str | None:
    """The attack whose cell has the lowest mean, among ``among`` (in that order: the first wins a tie);
    None when no cell of ``among`` is there."""
    present = [a for a in among if cells.get(a)]
    return min(present, key=lambda a: cells[a]["mean"]) if present else None


def returns_of(cell: dict) -> list[float]:
    """Each episode's return in a cell (a list of ``episodes`` with their ``return``), in the order of its env
    seeds."""
    return [episode["return"] for episode in cell["episodes"]]


def paired_drop(clean: dict, attacked: dict) -> dict:
    """The drop of ``attacked`` from ``clean``, two cells of the same episodes (each a list of ``episodes`` with
    their ``return``): mean, and a Student-t 95% interval of the per-episode differences, in return and in % of
    the clean mean."""
    clean_returns = np.array(returns_of(clean))
    diff = clean_returns - np.array(returns_of(attacked))
    half = half_width(diff)
    base = abs(clean_returns.mean()) or 1.0
    mean = float(diff.mean())
    return {"drop": mean, "ci95": float(half), "drop_pct": -100 * mean / base,
            "ci95_pct": [-100 * (mean + half) / base, -100 * (mean - half) / base]}


def paired_difference(first: dict[int, float], second: dict[int, float]) -> dict:
    """How far ``first`` leads ``second``: two defenses' returns per training seed (each a mean over the same
    episodes), differenced seed by seed over the seeds both have; the mean difference, the half-width of its Student-t
    95% interval over those seeds (nan for fewer than two), the seeds, and whether the interval leaves 0 out (the
    table separates the two)."""
    shared = sorted(set(first) & set(second))
    differences = np.array([first[s] - second[s] for s in shared], dtype=float)
    half = half_width(differences)
    mean = float(differences.mean()) if shared else float("nan")
    # no interval (fewer than two seeds: nan) separates nothing: a comparison with nan is False
    return {"difference": mean, "ci95": float(half), "seeds": shared, "separated": bool(abs(mean) > half)}


def episodes_to_pin(drop: dict, episodes: int) -> int | None:
    """None when ``drop``'s 95% interval (a :func:`paired_drop` of ``episodes``) is narrower than the drop it
    reports; else about how many episodes would make it so: the interval narrows as 1/sqrt(episodes), taken half
    again as many for the noise of the drop itself, rounded up to tens (no drop at all: ten times as many)."""
    low, high = drop["ci95_pct"]
    width, size = high - low, abs(drop["drop_pct"])
    if width < size:
        return None
    wanted = 1.5 * episodes * (width / size) ** 2 if size else 10 * episodes
    return int(math.ceil(wanted / 10) * 10)
