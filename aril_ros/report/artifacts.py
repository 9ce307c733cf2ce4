"""The files a report evaluates: per (defense, env, mode, training seed) a policy and the ARIL-A
trained against it, and for DAgger the surrogate its transfer row attacks and the directed ARIL-A of its directed row.
Seed 0 is the bundled policy and its bundled adversaries and surrogate; another seed is trained here by the bundled
policy's own settings (its provenance) with ``seed`` changed."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

from .. import dagger, gail
from ..adversary import ready_adversary, trained_for
from ..args import command_line
from ..policy import load_weights
from ..provenance import settings_of
from ..registry import PER_MODE_POLICIES, adversary_path, bundled_file, directed_adversary_path, surrogate_path
from ..sweep import Kept, Produced, Shipped, run_tasks
from ..verdict import ready_surrogate, surrogate_fits
from .jobs import FAILURES


def train_seed(defense: str, env: str, mode: str, seed: int, out: Path, run_dir: Path | None) -> Path:
    """Seed ``seed`` of a defense: the bundled policy's own settings with ``seed`` (and where it goes) changed."""
    provenance = load_weights(bundled_file(defense, env, mode))[0]["provenance"]
    if defense == "gail":
        # GAIL keeps its best policy so far in its out file while it trains: train beside ``out`` so that an
        # existing ``out`` means a finished training (an interrupted report resumes from it)
        partial = out.with_name(f"{out.stem}.partial.pt")
        cfg = settings_of(provenance, gail.GailConfig, seed=seed, out=str(partial))
        print(f"[report] training {out.stem}: {command_line('aril train-gail', cfg)}", flush=True)
        gail.train_gail(cfg, log=print)
        os.replace(partial, out)
        return out
    # a task of one CPU: ARIL's round candidates one after the other in it, whatever the bundled run used
    cfg = settings_of(provenance, dagger.LearnerConfig, seed=seed, out=str(out), run_dir=str(run_dir), workers=1,
                      address="")
    print(f"[report] training {out.stem}: {command_line('aril train-learner', cfg)}", flush=True)
    trained = Path(dagger.train_learner(cfg, log=print))
    # the run directory served resuming an interrupted training (ARIL's last for hours on one CPU); the finished
    # file's provenance has its rounds, and the directory is large (the aggregated data set: tens of MB)
    shutil.rmtree(Path(run_dir).resolve())  # as a task, the path is a link to the kept folder (sweep.Kept)
    return trained


def train_seed_adversary(env: str, mode: str, policy: Path, eps: float, steps: int, out: Path,
                         adversary_policy: str = "categorical") -> Path:
    return ready_adversary(out, str(policy), env, mode, eps, "expert", steps, False, print, policy=adversary_policy)


class Artifacts:
    """Policy and adversary files per (defense, env, mode, seed): the bundled ones for seed 0, trained
    into ``work_dir`` otherwise, as tasks (``workers`` CPUs of a local Ray, or the cluster at ``address``). A file
    that cannot be had is recorded in ``missing`` with the reason."""

    def __init__(self, work_dir: str | Path, workers: int, address: str, adversary_steps: int, log):
        self.work, self.workers, self.address = Path(work_dir), workers, address
        self.adversary_steps, self.log = adversary_steps, log
        self.missing: dict[tuple, str] = {}

    def _prepare(self, kind: str, wanted: dict[tuple, Path | Exception], fn, calls: dict[Path, tuple]) -> dict:
        """``wanted`` maps each combo to its file (or the error that stops it); ``calls`` makes the files
        not there yet (one call per file: a mode-independent policy is shared by both modes)."""
        made = {out: out for out in calls if out.exists()}
        todo = [out for out in calls if out not in made]
        if todo:
            self.log(f"[report] {len(todo)} {kind} files to train", flush=True)
        for index, result in run_tasks(fn, [calls[out] for out in todo], self.workers, self.address, failures=FAILURES,
                                       label=f"{kind} trainings", log=self.log):
            made[todo[index]] = result
        files = {}
        for combo, file in wanted.items():
            result = made.get(file, file)
            if isinstance(result, Exception):
                self.missing[(kind, *combo)] = str(result)
                self.log(f"[report] no {kind} for {' '.join(map(str, combo))}: {result}", flush=True)
                result = None
            files[combo] = result
        return files

    def policies(self, combos: list[tuple]) -> dict[tuple, Path | None]:
        """Each (defense, env, mode, seed)'s policy file, or None."""
        wanted, calls = {}, {}
        for defense, env, mode, seed in combos:
            try:
                bundled = bundled_file(defense, env, mode)
            except FAILURES as err:
                wanted[(defense, env, mode, seed)] = err
                continue
            if seed == 0:
                wanted[(defense, env, mode, seed)] = bundled
                continue
            name = f"{defense}-{env}{f'-{mode}' if defense in PER_MODE_POLICIES else ''}-seed{seed}"
            out = self.work / "policies" / f"{name}.pt"
            wanted[(defense, env, mode, seed)] = out
            run_dir = None if defense == "gail" else Kept(self.work / "learners" / name)  # GAIL keeps no rounds
            calls.setdefault(out, (defense, env, mode, seed, Produced(out), run_dir))
        return self._prepare("policy", wanted, train_seed, calls)

    def adversaries(self, policies: dict[tuple, Path | None], eps: dict[tuple, float], directed: bool = False
                    ) -> dict[tuple, Path | None]:
        """The ARIL-A trained against each policy: the bundled one for seed 0 (when made for this eps); ``directed``:
        the directed ARIL-A (``policy:=directed``) against each DAgger policy, for DAgger's directed row."""
        wanted, calls = {}, {}
        for (defense, env, mode, seed), policy in policies.items():
            if policy is None or (directed and defense != "dagger"):
                continue
            bundled = directed_adversary_path(env, mode) if directed else adversary_path(env, mode, defense)
            if seed == 0 and trained_for(bundled, eps[env, mode], str(policy), env, mode):
                wanted[(defense, env, mode, seed)] = bundled
                continue
            folder = "directed-adversaries" if directed else "adversaries"
            out = self.work / folder / f"{env}-{mode}-{defense}-seed{seed}.pt"
            wanted[(defense, env, mode, seed)] = out
            calls[out] = (env, mode, Shipped(policy), eps[env, mode], self.adversary_steps, Produced(out),
                          "directed" if directed else "categorical")
        return self._prepare("directed adversary" if directed else "adversary", wanted, train_seed_adversary, calls)

    def surrogates(self, policies: dict[tuple, Path | None], eps: dict[tuple, float], horizon: int
                   ) -> dict[tuple, Path | None]:
        """The surrogate of each DAgger policy that DAgger's transfer row attacks: the bundled one for seed 0 (when
        fitted at this eps and horizon), else fitted here (seconds each: in this process, not as tasks)."""
        files = {}
        for (defense, env, mode, seed), policy in policies.items():
            if defense != "dagger" or policy is None:
                continue
            bundled = surrogate_path(env, mode)
            if seed == 0 and surrogate_fits(bundled, "dagger", env, mode, eps[env, mode], horizon):
                files[(defense, env, mode, seed)] = bundled
                continue
            out = self.work / "surrogates" / f"{env}-{mode}-dagger-seed{seed}.pt"
            try:
                files[(defense, env, mode, seed)] = ready_surrogate(str(policy), env, mode, eps[env, mode], out,
                                                                    horizon, self.log)
            except FAILURES as err:
                self.missing[("surrogate", defense, env, mode, seed)] = str(err)
                self.log(f"[report] no surrogate for {defense} {env} {mode} {seed}: {err}", flush=True)
                files[(defense, env, mode, seed)] = None
        return files


def aril_rounds(policies: dict) -> dict:
    """ARIL's per-round clean and attacked return, from each ARIL policy file's provenance."""
    curves = {}
    for (defense, env, mode, seed), path in policies.items():
        if defense != "aril" or path is None:
            continue
        provenance = load_weights(path)[0]["provenance"]
        settings = settings_of(provenance, dagger.LearnerConfig)
        rounds = provenance.get("rounds_log", [])
        curves[f"{env} {mode} seed {seed}"] = {
            "round": [r["round"] for r in rounds], "attacked": [r["return"] for r in rounds],
            "clean": [r.get("clean_return", r["return"]) for r in rounds],  # round 0: the expert's clean demos
            "selected": provenance.get("selected"), "adversary_steps": settings.adversary_steps,
            "warm_start": settings.warm_start, "adversary_seeds": settings.adversary_seeds}
    return curves
