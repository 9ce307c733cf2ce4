"""Graph throughput: steps/s of the ROS 2 graph per mode, with and without recording, as a ratio to the bare
rclpy chain (:mod:`benchmarks.graph.bare_chain`: the same four roles, nothing else) measured beside it, and the
in-process engine.

    .venv/bin/python -m benchmarks.graph.bench_graph env:=HalfCheetah-v5 steps:=2000

The graph figure is ``steps_per_s`` of the orchestrator behind ``run_graph.py`` (episodes only,
start-up excluded); the bare chain is measured beside each mode's graph cells, in turn with them (``repeats``),
so that a load that comes and goes on the machine touches both alike. The engine runs the same policy, expert, attack and
episode length with one env (``n_envs:=1``, like the graph) and with 32. Then the query-based attacks
(``probe_attacks``: SPSA^k, FGSM^k by finite differences, ARIL-A + search), sensory, with the policy node asked a
step's probes in batches and one message a probe (``probe_batches:=false``), in turn, best of ``repeats``, and
their ratio. The last line is the figures as JSON (what ``aril report`` reads: this module is the
``aril_ros.benchmarks`` entry point ``graph``).
"""
import json
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from aril_ros.args import arg, comma_list, module_config
from aril_ros.attacks import make_attack
from aril_ros.envs import layout_of
from aril_ros.policy import resolve_policy
from aril_ros.protocol import ros_domain
from aril_ros.registry import DEFAULT_ENV, MAX_EPS, MODES, TABLE_SEARCH, attack_for_mode, check_name
from aril_ros.rollout import RolloutEngine
from aril_ros.scorecard import BUDGETS
from aril_ros_nodes.orchestrator import GraphConfig, GraphError, Orchestrator, allocate_domain
from benchmarks.graph import bare_chain


FULL = BUDGETS["full"]
PROBE_ATTACKS = {"spsa": {"attack": "spsa", "k": FULL.spsa_iterations, "samples": FULL.spsa_samples},
                 "fd_fgsm": {"attack": "fd_fgsm", "k": FULL.fd_iterations},
                 "search": {"attack": "aril_a", "search": TABLE_SEARCH, "rescale": True}}
"""The query-based attacks at the full budget's settings (ARIL-A + search at the tables' 16 candidates)."""


@dataclass
class GraphBenchConfig:
    """Arguments of ``python -m benchmarks.graph.bench_graph``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    steps: int = arg(2000, "steps per graph measurement (whole episodes of this length)", low=1, high=10**9)
    eps: float = arg(0.05, "attack budget", low=0.0, high=MAX_EPS)
    bare_steps: int = arg(2000, "steps per bare-chain measurement", low=1, high=10**9)
    probe_attacks: str = arg(",".join(PROBE_ATTACKS), "comma-separated query-based attacks to time with probes in "
                                                        f"batches and one a message ({', '.join(PROBE_ATTACKS)}; "
                                                        "empty: none)")
    probe_steps: int = arg(200, "steps per query-based attack's run", low=1, high=10**9)
    repeats: int = arg(1, "runs of the bare chain, the graph and the graph with recording per mode, in turn; each "
                          "cell is the best of them", low=1, high=20)


def graph_steps_per_s(cfg, mode: str, record: bool) -> float:
    """The orchestrator's ``steps_per_s`` for two episodes of ``steps / 2`` (the default policy and expert)."""
    with tempfile.TemporaryDirectory(prefix="aril_bench_graph-") as folder:  # the writer takes new files only
        graph = GraphConfig(mode=mode, env=cfg.env, attack=attack_for_mode(mode), eps=cfg.eps, episodes=2,
                            horizon=cfg.steps // 2, record=str(Path(folder) / "run.mcap") if record else "off")
        try:
            return Orchestrator(graph, log=lambda *a, **k: None).run()["steps_per_s"]
        except (ValueError, GraphError) as err:
            raise SystemExit(f"the graph run ({mode}) failed: {err}") from None


def probe_steps_per_s(cfg, knobs: dict, batches: bool) -> tuple[float, float]:
    """Steps/s and probes per step of one sensory episode of ``probe_steps`` under a query-based attack, the probes
    in batches or one a message."""
    graph = GraphConfig(mode="sensory", env=cfg.env, eps=cfg.eps, episodes=1, horizon=cfg.probe_steps, record="off",
                        probe_batches=batches, **knobs)
    try:
        summary = Orchestrator(graph, log=lambda *a, **k: None).run()
    except (ValueError, GraphError) as err:
        raise SystemExit(f"the graph run ({knobs}) failed: {err}") from None
    return summary["steps_per_s"], summary["queries_per_step"]


def engine_steps_per_s(cfg, mode: str, n_envs: int) -> float:
    policy, expert = resolve_policy("bundled", cfg.env), resolve_policy("expert", cfg.env)  # the graph's two
    attack = make_attack(attack_for_mode(mode), layout_of(cfg.env), cfg.eps)
    engine = RolloutEngine(cfg.env, policy, expert, attack, mode, n_envs=n_envs, horizon=cfg.steps // 2)
    started = time.perf_counter()
    traj = engine.rollout(max(2, n_envs), seed=0)
    return int(traj.length.sum()) / (time.perf_counter() - started)


def bare_chain_steps_per_s(steps: int, mark=lambda: None) -> float:
    domain, lock = allocate_domain("auto")
    try:
        with ros_domain(domain):  # the chain's simulator runs in this process
            return bare_chain.steps_per_s(steps, dict(os.environ), mark)
    finally:
        lock.close()


def main(argv):
    cfg = module_config(GraphBenchConfig, "python -m benchmarks.graph.bench_graph", __doc__, argv)
    if cfg is None:
        return
    import torch

    torch.set_num_threads(1)
    rows = {}
    for mode in MODES:
        # the three compared cells take turns, best of `repeats` each: a load that comes and goes on a shared
        # machine slows one run of a cell, seldom all of them
        compared = {"bare chain": lambda: bare_chain_steps_per_s(cfg.bare_steps),
                    "graph": lambda: graph_steps_per_s(cfg, mode, record=False),
                    "graph+record": lambda: graph_steps_per_s(cfg, mode, record=True)}
        runs = [{cell: measure() for cell, measure in compared.items()} for _ in range(cfg.repeats)]
        rows[mode] = {**{cell: max(run[cell] for run in runs) for cell in compared},
                      "engine n_envs=1": engine_steps_per_s(cfg, mode, 1),
                      "engine n_envs=32": engine_steps_per_s(cfg, mode, 32)}
    probes = {}
    for name in comma_list(cfg.probe_attacks):
        knobs = PROBE_ATTACKS[check_name("probe attack", name, tuple(PROBE_ATTACKS))]
        runs = [{batches: probe_steps_per_s(cfg, knobs, batches) for batches in (True, False)}
                for _ in range(cfg.repeats)]
        batched, single = (max(run[batches][0] for run in runs) for batches in (True, False))
        probes[name] = {"probes per step": runs[0][True][1], "in batches": round(batched, 1),
                        "one a message": round(single, 1), "batches / one a message": round(batched / single, 2)}
    ratios = {mode: {f"{cell} / bare": round(row[cell] / row["bare chain"], 2) for cell in ("graph", "graph+record")}
              for mode, row in rows.items()}
    columns, ratio_columns = list(rows["clean"]), list(ratios["clean"])
    print(f"{cfg.env}: steps/s ({cfg.steps} graph steps, {cfg.bare_steps} bare-chain steps per run, best of "
          f"{cfg.repeats})")
    print(f"{'mode':<10}" + "".join(f"{c:>18}" for c in columns) + "".join(f"{c:>21}" for c in ratio_columns))
    for mode, row in rows.items():
        print(f"{mode:<10}" + "".join(f"{row[c]:>18.0f}" for c in columns)
              + "".join(f"{ratios[mode][c]:>21.2f}" for c in ratio_columns))
    if probes:
        print(f"query-based attacks, sensory: steps/s ({cfg.probe_steps} steps per run, best of {cfg.repeats})")
        print(f"{'attack':<10}{'probes/step':>12}{'in batches':>12}{'one a message':>15}{'ratio':>8}")
        for name, row in probes.items():
            print(f"{name:<10}{row['probes per step']:>12g}{row['in batches']:>12.0f}{row['one a message']:>15.0f}"
                  f"{row['batches / one a message']:>8.2f}")
    print(json.dumps({"env": cfg.env, **{m: {**{k: round(v, 1) for k, v in r.items()}, **ratios[m]}
                                         for m, r in rows.items()}, "probes": probes}))


if __name__ == "__main__":
    main(sys.argv[1:])
