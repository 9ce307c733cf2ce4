"""The ``aril`` command (also ``python -m aril_ros``): subcommands with ``key:=value`` arguments.

    aril eval env:=HalfCheetah-v5 policy:=expert mode:=sensory attack:=random eps:=0.05
    aril train-expert env:=Ant-v5 steps:=300000

Progress goes to stderr; results to stdout, ending with one JSON line.
"""
from __future__ import annotations

import json
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from . import plugins
from .adversary import AdversaryConfig, train_adversary
from .args import ArgumentError, arg, parse_args, usage
from .dagger import train_learner
from .envs import EnvLayoutError
from .evaluation import EvalConfig, evaluate
from .experiments import (AttackTableConfig, CalibrationConfig, DefenseTableConfig, attack_table, calibrate_eps,
                          defense_table)
from .experts import ExpertConfig, train_expert
from .export import ExportConfig, export
from .gail import GailConfig, train_gail
from .learner_config import LearnerConfig
from .learners import BCConfig, train_bc
from .onboard import OnboardConfig, onboard
from .policy import PolicyFileError
from .render import RenderConfig, RenderError, render
from .report import ReportConfig, build_report
from .runlog import RunLogError, recover
from .scan import ScanConfig, scan_adversary
from .scorecard import ScorecardConfig, scorecard
from .timing_table import TimingTableConfig, timing_table
from .validated import ValidateConfig, validate_defense
from .verdict import FitSurrogateConfig, fit_surrogate_command


def run_eval(cfg: EvalConfig) -> dict:
    summary = evaluate(cfg, lambda episode: print(episode.line(), file=sys.stderr, flush=True))
    print(f"{cfg.env} {cfg.mode}/{summary['attack']} eps={summary['eps']}: return "
          f"{summary['mean_return']:.1f} ± {summary['std_return']:.1f} over {cfg.episodes} episodes, "
          f"mean expert loss {summary['mean_expert_loss']:.4f}, {summary['steps_per_s']:.0f} steps/s")
    print(json.dumps(summary))
    return summary


@dataclass
class RecoverConfig:
    """Arguments of ``aril log-recover``."""

    input: str = arg("", "a run log that was cut short (the run was killed) or damaged; a closed, readable one is "
                         "refused")
    out: str = arg("", "where to write the recovered log, a new file (default: <input>.recovered.mcap)")


def run_recover(cfg: RecoverConfig) -> int:
    recovery = recover(cfg.input, cfg.out or str(Path(cfg.input).with_suffix("")) + ".recovered.mcap")
    print(recovery.text())
    return recovery.steps


@dataclass
class Command:
    """A subcommand of ``aril``: its arguments dataclass, what runs it, and one line for the listing.
    Other packages add commands through the ``aril_ros.commands`` entry points (see :mod:`aril_ros.plugins`)."""

    config: type
    run: Callable
    summary: str


COMMANDS = {
    "eval": Command(EvalConfig, run_eval, "Evaluate a policy under a mode, attack and eps, labelled by the expert."),
    "train-expert": Command(ExpertConfig, train_expert, "Train an expert with stable-baselines3 SAC and export it."),
    "train-bc": Command(BCConfig, train_bc, "Behaviour-clone a learner from clean expert demonstrations."),
    "train-learner": Command(LearnerConfig, train_learner, "Imitate by rounds: algorithm:=dagger, dart, dr (domain "
                             "randomisation) or aril (Algorithm 1)."),
    "train-gail": Command(GailConfig, train_gail,
                          "GAIL: a discriminator's reward for stable-baselines3 PPO (no expert labels)."),
    "train-adversary": Command(AdversaryConfig, train_adversary,
                               "Train the learned ARIL-A adversary against a policy (PPO on the in-process engine)."),
    "scan-adversary": Command(ScanConfig, scan_adversary, "A hyperparameter scan of ARIL-A against a policy: every "
                              "point trained and evaluated as a Ray task (local or a cluster), ranked."),
    "calibrate-eps": Command(CalibrationConfig, calibrate_eps,
                             "Pick eps per env and mode by the paper's rule (FGSM drop <= 40%)."),
    "attack-table": Command(AttackTableConfig, attack_table,
                            "The paper's Adversary rows (clean, random, FGSM, FGSM^k, SPSA^k, ARIL-A) and the "
                            "black-box ones beside them (FGSM^k by finite differences, on a surrogate, ARIL-A + "
                            "search); writes results/."),
    "defense-table": Command(DefenseTableConfig, defense_table, "The paper's Robust IL rows: each defense under the "
                             "strongest attack against it; writes results/."),
    "validate-defense": Command(ValidateConfig, validate_defense, "Of learners trained for one env and mode, keep the "
                                "one whose worst attack (an ARIL-A trained against it among them) leaves it the most "
                                "return on validation episodes: the defense ARIL-V (candidates:=aril,dr)."),
    "timing-table": Command(TimingTableConfig, timing_table, "Each defense under its worst timing attack (late or "
                            "dropped observations, late actions; fixed, random and learned) over its training "
                            "seeds; writes results/timing.{json,md}."),
    "report": Command(ReportConfig, build_report,
                      "Regenerate docs/results.md: tables beside the paper's, eps sweeps, ARIL's rounds, performance."),
    "onboard": Command(OnboardConfig, onboard, "A new robot in one command: expert, DAgger learner and eps for a MuJoCo "
                       "env, resumable, into the user data folder ($ARIL_DATA)."),
    "scorecard": Command(ScorecardConfig, scorecard, "How robust is a policy: clean vs every attack on the same "
                         "episodes, paired drops, eps sweeps, the worst case; one page with figures."),
    "fit-surrogate": Command(FitSurrogateConfig, fit_surrogate_command, "Copy a policy from its answers alone (a "
                             "surrogate): what attack:=transfer runs FGSM^k on."),
    "render": Command(RenderConfig, render, "See an attack: episodes rendered offscreen side by side into a GIF."),
    "log-recover": Command(RecoverConfig, run_recover, "Rewrite the intact steps of a cut-short or damaged run log."),
    "export": Command(ExportConfig, export, "Run logs into a Minari dataset (observations seen, actions, rewards; "
                      "the true state, perturbation and expert label as infos), which the learners read back."),
}


def command(name: str) -> Command | None:
    """A library command, or one an installed package registers (e.g. ``replay`` from the ROS side)."""
    if name in COMMANDS:
        return COMMANDS[name]
    return plugins.load("aril_ros.commands", name) if name in plugins.names("aril_ros.commands") else None


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    chosen = command(argv[0]) if argv else None
    if chosen is None:
        print("usage: aril <command> [key:=value ...] [--help]\n\ncommands:")
        for name in [*COMMANDS, *plugins.names("aril_ros.commands")]:
            print(f"  {name:<14} {command(name).summary}")
        return 0 if not argv or argv[0] in ("-h", "--help") else 2
    if argv[0] == "report":  # the spelling: aril report --quick / --full
        argv = [f"budget:={a[2:]}" if a in ("--quick", "--full") else a for a in argv]
    if "-h" in argv[1:] or "--help" in argv[1:]:
        print(usage(chosen.config, f"aril {argv[0]}", chosen.summary))
        return 0
    try:
        chosen.run(parse_args(chosen.config, argv[1:]))
    except (ArgumentError, EnvLayoutError, PolicyFileError, RunLogError, ValueError, OSError,
            RenderError) as err:
        print(f"aril {argv[0]}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"aril {argv[0]}: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
