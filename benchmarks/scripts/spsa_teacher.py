"""SPSA^k as the learned adversary's teacher (issue 14's last untried direction): distil where SPSA^k's
queries found the victim fragile into the categorical adversary, then go on with PPO on the paper's
objective, and compare each stage on the tuning record's protocol (``aril eval ... episodes:=10 seed:=1000``).

    python benchmarks/scripts/spsa_teacher.py env:=HalfCheetah-v5 mode:=sensory ppo_steps:=1000000

1. collect: the victim attacked by SPSA^k on training seeds; per step the adversary's input row (true state,
   the victim's unperturbed action, the expert's) and SPSA^k's perturbation;
2. distil: cross-entropy of the adversary's categorical head on each entry's nearest of {-eps, 0, +eps};
3. evaluate the distilled adversary, train it on with PPO (``aril train-adversary init:=``), evaluate again.

Writes ``<out>/distilled.pt``, ``<out>/ppo.pt`` and ends with one JSON line of the figures.
"""
from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from aril_ros import seeds
from aril_ros.adversary import AdversaryConfig, initial_adversary, train_adversary
from aril_ros.adversary_net import CHOICES, input_rows, save_adversary
from aril_ros.args import arg, parse_args
from aril_ros.attacks import make_attack
from aril_ros.envs import layout_of
from aril_ros.evaluation import EvalConfig, evaluate
from aril_ros.policy import resolve_policy
from aril_ros.provenance import stamp
from aril_ros.registry import calibrated_eps
from aril_ros.rollout import RolloutEngine


@dataclass
class TeacherConfig:
    """Arguments of ``benchmarks/scripts/spsa_teacher.py``."""

    env: str = arg("HalfCheetah-v5", "gymnasium MuJoCo env id")
    mode: str = arg("sensory", "sensory or physical")
    victim: str = arg("dagger", "the attacked policy (bundled name or file)")
    episodes: int = arg(16, "SPSA^k-attacked episodes whose steps are the distillation set")
    epochs: int = arg(30, "passes over the distillation set")
    ppo_steps: int = arg(1_000_000, "PPO steps after distillation (0: distil only)")
    eval_episodes: int = arg(10, "episodes per evaluation (the tuning record's 10)")
    eval_seed: int = arg(seeds.CALIBRATION, "env seed of the first evaluation episode (the tuning record's 1000)")
    out: str = arg("runs/spsa-teacher", "folder of the two adversary files")


def collect(cfg: TeacherConfig, eps: float, victim, expert) -> tuple[np.ndarray, np.ndarray]:
    """The adversary's input rows on SPSA^k-attacked steps and SPSA^k's zero-order perturbations."""
    layout = layout_of(cfg.env)
    spsa = make_attack("spsa", layout, eps, victim=victim, expert=expert)
    engine = RolloutEngine(cfg.env, victim, expert, spsa, cfg.mode, n_envs=16)
    states, clean, labels, deltas = [], [], [], []
    for step in engine.iter_steps(cfg.episodes, seed=seeds.adversary_training(7)):
        states.append(step.true_obs)
        clean.append(victim.act(step.true_obs))
        labels.append(step.expert_action)
        deltas.append(step.delta[:, :layout.n_position])
    engine.close()
    return (np.concatenate(states), np.concatenate(clean), np.concatenate(labels)), np.concatenate(deltas)


def distil(cfg: TeacherConfig, eps: float, answers, deltas: np.ndarray) -> Path:
    """A categorical adversary fitted to SPSA^k's choices; its input scaling from the same rows."""
    adv_cfg = AdversaryConfig(env=cfg.env, mode=cfg.mode, eps=eps)
    layout = layout_of(cfg.env)
    rows = input_rows(adv_cfg.inputs, *answers)
    net = initial_adversary(adv_cfg, rows.mean(0), rows.std(0) + 1e-3)
    target = torch.as_tensor(np.clip(np.rint(deltas / eps), -1, 1) + 1, dtype=torch.long)
    x = torch.as_tensor(rows, dtype=torch.float32)
    optimizer = torch.optim.Adam(net.mean_net.parameters(), lr=1e-3)
    gen = torch.Generator().manual_seed(0)
    for epoch in range(cfg.epochs):
        for idx in torch.randperm(len(x), generator=gen).split(1024):
            logits = net.mean_net(net.normalise(x[idx])).reshape(len(idx), layout.n_position, CHOICES)
            loss = torch.nn.functional.cross_entropy(logits.reshape(-1, CHOICES), target[idx].reshape(-1))
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    with torch.no_grad():
        logits = net.mean_net(net.normalise(x)).reshape(len(x), layout.n_position, CHOICES)
        agreement = (logits.argmax(-1) == target).float().mean().item()
    print(f"[spsa-teacher] distilled {len(x)} steps, final loss {loss.item():.3f}, "
          f"agreement with SPSA^k {agreement:.3f}", flush=True)
    net.meta["provenance"] = {**stamp("benchmarks/scripts/spsa_teacher.py", cfg), "teacher": "spsa",
                              "victim": cfg.victim, "steps": 0, "distilled_steps": len(x), "agreement": agreement}
    return save_adversary(net.eval(), Path(cfg.out) / "distilled.pt")


def attacked_return(cfg: TeacherConfig, adversary: Path) -> float:
    return evaluate(EvalConfig(env=cfg.env, policy=cfg.victim, mode=cfg.mode, attack="aril_a",
                               attack_file=str(adversary), episodes=cfg.eval_episodes, seed=cfg.eval_seed))["mean_return"]


def main(argv):
    cfg = parse_args(TeacherConfig, argv)
    torch.set_num_threads(1)
    Path(cfg.out).mkdir(parents=True, exist_ok=True)
    eps = calibrated_eps(cfg.env, cfg.mode)
    victim, expert = resolve_policy(cfg.victim, cfg.env, cfg.mode), resolve_policy("expert", cfg.env)
    started = time.time()
    answers, deltas = collect(cfg, eps, victim, expert)
    distilled = distil(cfg, eps, answers, deltas)
    figures = {"env": cfg.env, "mode": cfg.mode, "eps": eps, "distilled_steps": len(deltas),
               "distilled_return": round(attacked_return(cfg, distilled), 1)}
    print(f"[spsa-teacher] distilled adversary: victim return {figures['distilled_return']}", flush=True)
    if cfg.ppo_steps:
        trained = train_adversary(AdversaryConfig(env=cfg.env, mode=cfg.mode, eps=eps, victim=cfg.victim,
                                                  steps=cfg.ppo_steps, init=str(distilled),
                                                  out=str(Path(cfg.out) / "ppo.pt")))
        figures.update(ppo_steps=cfg.ppo_steps, ppo_return=round(attacked_return(cfg, trained), 1))
    figures["seconds"] = round(time.time() - started)
    print(json.dumps(figures))


if __name__ == "__main__":
    main(sys.argv[1:])
