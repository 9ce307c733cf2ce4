"""How much compute a report's protocol took, from the times its tasks recorded, and how long it would take on N
cores: the protocol runs in three stages (policy trainings, the adversaries against them, the evaluations), each
a set of independent one-CPU tasks, so a stage takes at least its CPU time over N and at least its longest task."""
from __future__ import annotations

from pathlib import Path

from ..adversary_net import load_adversary
from ..policy import load_policy

CORES = (1, 2, 8, 32, 128)
"""The machine sizes the report estimates for."""


def training_seconds(provenance: dict) -> float | None:
    """The CPU seconds a file's training took, as its provenance records them (ARIL's side-by-side round
    adversaries counted at their own times: ``cpu_seconds``), or None for a file that recorded none."""
    return provenance.get("cpu_seconds", provenance.get("train_seconds"))


def stage(seconds: list[float | None]) -> dict:
    known = [s for s in seconds if s is not None]
    return {"tasks": len(seconds), "untimed": len(seconds) - len(known), "cpu_hours": round(sum(known) / 3600, 3),
            "longest_hours": round(max(known, default=0.0) / 3600, 3)}


def compute_summary(policies: set[Path], adversaries: set[Path], evaluation_seconds: list[float | None]) -> dict:
    """CPU-hours per stage and in all (the bundled seed-0 files' own trainings included, read from their
    provenance), and the hours the protocol would take on each of :data:`CORES` cores."""
    stages = {"policy trainings": stage([training_seconds(load_policy(p).meta.provenance) for p in policies]),
              "adversary trainings": stage([training_seconds(load_adversary(a).meta["provenance"])
                                            for a in adversaries]),
              "evaluations": stage(evaluation_seconds)}
    return {"stages": stages, "cpu_hours": round(sum(s["cpu_hours"] for s in stages.values()), 2),
            "hours_on_cores": {n: round(sum(max(s["cpu_hours"] / n, s["longest_hours"]) for s in stages.values()), 2)
                               for n in CORES}}


def compute_lines(summary: dict) -> list[str]:
    """The report's paragraph on compute."""
    stages = summary["stages"]
    parts = [f"{name} {s['cpu_hours']:.2f} ({s['tasks']} task{'s' * (s['tasks'] != 1)}"
             + (f", {s['untimed']} of them with no recorded time" if s["untimed"] else "")
             + f", the longest {s['longest_hours']:.2f})" for name, s in stages.items()]
    hours = ", ".join(f"{n} core{'s' * (int(n) != 1)} ~{h:g} h" for n, h in summary["hours_on_cores"].items())
    return [f"- Compute: {summary['cpu_hours']:.2f} CPU-hours in all: " + "; ".join(parts) + ". Each stage's tasks "
            "are independent one-CPU tasks, so on N cores a stage takes at least its CPU time over N and at least "
            f"its longest task: {hours} (from the measured per-task times; `docs/scaling.md` runs it on a cluster)."]
