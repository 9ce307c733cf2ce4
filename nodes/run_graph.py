"""Run attacked episodes through the ROS 2 graph: ``python run_graph.py mode:=sensory [key:=value ...]``.

Starts the simulator, attacker, policy and expert nodes as processes in a ROS domain of their own,
runs the episodes in lockstep, records them to MCAP and prints per-episode figures, then, for an attacked
mode, the clean return of the same episodes beside the attacked one, and one JSON summary line.
``--help`` lists the arguments. The checkout's ``run_graph.py`` installs what it needs on
first use and runs this; ``python -m aril_ros_nodes.run_graph`` runs it from the installed package.

Exit codes: 0 for a complete run, 1 for a refused argument or a failed run, 128 + the signal's number
for a run stopped by a signal (130 for Ctrl-C, 143 for SIGTERM).
"""
import dataclasses
import json
import os
import sys
from pathlib import Path

from aril_ros.args import parse_args, usage
from aril_ros.registry import PER_MODE_POLICIES, bundled_file
from aril_ros.timing import TimingBudget
from aril_ros_nodes.orchestrator import GraphConfig, GraphError, Orchestrator, RunInterrupted

EXAMPLES = """examples:
  python run_graph.py mode:=sensory                       # DAgger under the ARIL-A trained against it, beside clean
  python run_graph.py mode:=physical policy:=aril episodes:=5   # ARIL under the ARIL-A trained against it
  python run_graph.py mode:=sensory policy:=external domain:=42 attack:=spsa   # your own node (msgs_doc/README.md)"""


def clean_baseline(cfg: GraphConfig, attacked: dict) -> dict:
    """The clean figures of the attacked run's episodes (the same env seeds): from the in-process engine, which is
    bit-identical to the graph for a policy file or bundled name; for an external node, which the engine cannot
    run, from a clean run of the graph with it (recorded beside the attacked log)."""
    if cfg.policy == "external":
        record = (str(Path(attacked["record"]).with_suffix("")) + "-clean.mcap") if attacked["record"] else "off"
        clean = dataclasses.replace(cfg, mode="clean", attack="", attack_file="", search=0, rescale=False, k=0,
                                    samples=0, eps=0.0, delay=0, drop=0.0, action_delay=0, record=record,
                                    domain=str(attacked["domain"]))
        return {**Orchestrator(clean, log=lambda *a, **k: None).run(), "source": "graph"}
    from aril_ros.evaluation import EvalConfig, evaluate

    # a per-mode learner is the attacked mode's file; clean mode alone would not know which
    policy = str(bundled_file(cfg.policy, cfg.env, cfg.mode)) if cfg.policy in PER_MODE_POLICIES else cfg.policy
    figures = evaluate(EvalConfig(env=cfg.env, policy=policy, expert=cfg.expert, mode="clean", episodes=cfg.episodes,
                                  seed=cfg.seed, horizon=cfg.horizon))
    return {**figures, "source": "engine"}


def comparison(summary: dict) -> str:
    """The attacked run beside its clean baseline, for the terminal."""
    clean = summary["clean"]
    how = ("the engine, bit-identical to the graph" if clean["source"] == "engine"
           else "a clean run of the graph with the external node")
    seeds = f"env seeds {summary['seed']}..{summary['seed'] + summary['episodes'] - 1}"
    return "\n".join([
        f"[run_graph] {summary['env']} {summary['mode']}, {summary['attack']} at eps {summary['eps']:g}"
        + (timed(summary["timing"]) if "timing" in summary else "") + " on "
        f"{summary['policy']}, {summary['episodes']} episode(s), {seeds}:",
        f"  clean     return {clean['mean_return']:9.1f}   expert loss {clean['mean_expert_loss']:.4f}   ({how})",
        f"  attacked  return {summary['mean_return']:9.1f}   expert loss {summary['mean_expert_loss']:.4f}   "
        f"drop {summary['drop_pct']:+.1f}% of clean",
        f"  log       {summary['record'] or '(not recorded: record:=off)'}"])


def timed(record: dict) -> str:
    """A timing attack's record (:meth:`aril_ros.timing.TimingAttack.record`) as the comparison names it."""
    budget = TimingBudget(**{field.name: record[field.name] for field in dataclasses.fields(TimingBudget)})
    return f", {budget.described()}" + (f" ({record['chooser']})" if record["chooser"] != "fixed" else "")


def main(argv) -> int:
    if "-h" in argv or "--help" in argv:
        print(usage(GraphConfig, "python run_graph.py", __doc__.strip().splitlines()[0]) + "\n\n" + EXAMPLES)
        return 0
    try:
        cfg = parse_args(GraphConfig, argv)
        summary = Orchestrator(cfg, log=print).run()
        if (cfg.mode != "clean" or "timing" in summary) and cfg.baseline:
            clean = clean_baseline(cfg, summary)
            summary["clean"] = {key: clean[key] for key in ("mean_return", "std_return", "mean_expert_loss",
                                                             "returns", "source")}
            summary["drop_pct"] = round(-100 * (clean["mean_return"] - summary["mean_return"])
                                        / (abs(clean["mean_return"]) or 1.0), 2)
            print(comparison(summary))
    except (ValueError, GraphError) as err:  # bad arguments, ids, files (all ValueErrors) or a failed run
        print(f"run_graph: error: {err}", file=sys.stderr)
        return 1
    except RunInterrupted as err:  # a stop signal during the run: 130 for SIGINT, 143 for SIGTERM
        print(f"run_graph: {err}; nodes stopped, log closed as interrupted", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:  # Ctrl-C before the run began: nothing started yet
        print("run_graph: interrupted before the run began", file=sys.stderr)
        return 130
    print(json.dumps(summary))
    return 0


def run_and_exit(argv) -> None:
    """:func:`main`, then end the process at once. The run is over (nodes stopped, log closed, DDS participant
    gone): Python's own teardown of torch and the DDS libraries would keep the user waiting 1-2.5 s more on
    a loaded machine."""
    try:
        code = main(argv)
        sys.stdout.flush()
        sys.stderr.flush()
    except BrokenPipeError:  # the reader left early (`run_graph.py --help | head`): nothing more to tell it
        code = 1  # as Python itself ends on a broken pipe, without its traceback
    os._exit(code)


if __name__ == "__main__":
    run_and_exit(sys.argv[1:])
