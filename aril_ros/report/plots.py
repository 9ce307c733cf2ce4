"""The report's figures as PNG (matplotlib, imported only when a figure is drawn): return vs eps per
defense and attack, and ARIL's clean and attacked return per round; and a scorecard's return vs eps per attack."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..registry import ATTACKS, DEFENSES, PAPER_DEFENSES, SCORECARD_ATTACKS
from .stats import paired_drop, summarise


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_sweeps(evals: dict, env: str, mode: str, attacks: list[str], eps0: float, path: Path) -> None:
    """One panel per attack: each defense's return (mean, 95% interval) against eps, 0 being its clean run."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(attacks), figsize=(4.2 * len(attacks), 3.4), squeeze=False)
    for ax, attack in zip(axes[0], attacks):
        for defense in PAPER_DEFENSES:
            points = sorted((scale, summarise(r)) for (e, m, d, a, scale), r in evals.items()
                            if e == env and m == mode and d == defense and a in (attack, "none"))
            if not points:
                continue
            x = [scale * eps0 for scale, _ in points]
            y = np.array([s["mean"] for _, s in points])
            ci = np.nan_to_num(np.array([s["ci95"] for _, s in points]))
            ax.plot(x, y, marker="o", ms=3, label=DEFENSES[defense])
            ax.fill_between(x, y - ci, y + ci, alpha=0.15)
        ax.axvline(eps0, color="grey", lw=0.8, ls=":")
        ax.set_title(f"{ATTACKS[attack]}")
        ax.set_xlabel("eps (dotted: calibrated)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("return")
    axes[0][-1].legend(fontsize=8)
    fig.suptitle(f"{env}, {mode} attacks: return vs eps (mean, 95% interval)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_budget_sweeps(series: dict[str, dict[str, list[tuple[float, float, float]]]], panels: dict[str, str],
                       title: str, path: Path) -> None:
    """One panel per attack kind (``panels``: kind to its title): each row's return (mean, 95% interval) against the
    budget; ``series[row][kind]`` holds (budget, mean, half-width) points, budget 0 being the row's clean run."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.4), squeeze=False)
    for ax, (kind, panel) in zip(axes[0], panels.items()):
        for row, kinds in series.items():
            x, y, ci = (np.array(v, dtype=float) for v in zip(*kinds[kind]))
            ax.plot(x, y, marker="o", ms=3, label=row)
            ax.fill_between(x, y - np.nan_to_num(ci), y + np.nan_to_num(ci), alpha=0.15)
        ax.set_title(panel)
        ax.set_xlabel("budget (0: clean)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("return")
    axes[0][-1].legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_rounds(curves: dict, envs: list[str], modes: list[str], path: Path) -> None:
    """One panel per env and mode: each ARIL run's clean return and return under its round's adversary."""
    plt = _pyplot()
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


def plot_figures(evals: dict, curves: dict, envs: list[str], modes: list[str], sweep_attacks: list[str], eps: dict,
                 figures_dir: Path) -> None:
    """Every PNG of the report: a sweep per env and mode, and ARIL's rounds."""
    for mode in modes:
        for env in envs:
            plot_sweeps(evals, env, mode, sweep_attacks, eps[env, mode], figures_dir / f"sweep-{env}-{mode}.png")
    plot_rounds(curves, envs, modes, figures_dir / "aril-rounds.png")


def plot_scorecard_sweep(result: dict, scales: list[float], title: str, path: Path) -> None:
    """A scorecard's mode (``aril_ros.scorecard``'s ``modes`` entry): return against eps, one line per attack (mean
    and paired 95% interval), the clean return as a dashed line, the mode's eps dotted."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 3.6))
    clean = result["clean"]["mean_return"]
    for attack, sweep in result["attacks"].items():
        swept = [s for s in scales if s in sweep]  # through the graph only the worst attack is swept
        x = [sweep[s]["eps"] for s in swept]
        y = np.array([sweep[s]["mean_return"] for s in swept])
        half = np.nan_to_num([paired_drop(result["clean"], sweep[s])["ci95"] for s in swept])
        ax.plot(x, y, marker="o", ms=3, label=SCORECARD_ATTACKS[attack])
        ax.fill_between(x, y - half, y + half, alpha=0.12)
    ax.axhline(clean, color="black", lw=1, ls="--", label="clean")
    ax.axvline(result["eps"], color="grey", lw=0.8, ls=":")
    ax.set(xscale="log", xlabel="eps (dotted: the scorecard's)", ylabel="return", title=title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
