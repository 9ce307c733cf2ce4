"""Issue 14, item 3: bundle ARIL retrained with the new adversary in its loop, and each learner at the width its env
favours, with the ARIL-As that judged them as the defense table's adversaries.

The learners chosen below are the ones the tuning record (results/aril_a_tuning.md, sections "The expert holds",
"Every learner as wide" and "Each round's adversary the strongest of three") measured keeping the most return under
their worst attack, judged all alike: 20 episodes from env seed 3000 under random, FGSM, FGSM^k, SPSA^k and fresh
1M-step ARIL-As of training seeds 0, 1 and 2. ARIL is Algorithm 1 unchanged in every choice (only f_t differs: the
categorical ARIL-A, on Swimmer physical the strongest of three per round). DR moves to 256 wide where that held
more; DAgger, BC, DART and GAIL stay 64 wide (256 wide they held less on HalfCheetah, and the DAgger learner is the
attack table's victim and the quick start's).

A judging adversary is copied in as the defense table's adversary of its seed (``<env>-<mode>-<defense>[-seed<k>].pt``
in aril_ros/data/defense-adversary/) where that seed has none trained against the very file now bundled (its sha256,
as ``aril defense-table`` checks), and only if it was itself trained against that file, so
``aril defense-table adversary_seeds:=3`` then trains just the missing ones.

    .venv/bin/python benchmarks/scripts/bundle_widths.py
"""
import shutil
from pathlib import Path

from aril_ros.adversary import trained_for
from aril_ros.registry import DEFENSES, PAPER_ENVS, adversary_path, bundled_path, calibrated_eps

FRESH = Path("results/i14-fresh")
JUDGES = FRESH / "adversary-seeds"  # benchmarks/scripts/adversary-seeds.sh: <policy path, / as _>-seed<k>.pt
CHOSEN = {  # (defense, env, mode): the learner to bundle, its worst case in the tuning record
    ("aril", "HalfCheetah-v5", "sensory"): FRESH / "aril256-HalfCheetah-v5-sensory.pt",  # 4890.9 (DR 256: 4072.3)
    ("aril", "HalfCheetah-v5", "physical"): FRESH / "aril256-HalfCheetah-v5-physical.pt",  # 2291.7 (DR 256: 124.2)
    ("aril", "Ant-v5", "sensory"): FRESH / "aril256-Ant-v5-sensory.pt",  # 2476.7 (64 wide: 2342, one adversary)
    ("aril", "Ant-v5", "physical"): FRESH / "aril256-Ant-v5-physical.pt",  # 767.2 (strongest of three: 741.4)
    ("aril", "Swimmer-v5", "sensory"): FRESH / "aril256-Swimmer-v5-sensory.pt",  # 139.4 (64 wide: 133.3)
    ("aril", "Swimmer-v5", "physical"): FRESH / "aril-best3-64-Swimmer-v5-physical.pt",  # 151.6 (64 wide: -28)
    ("dr", "HalfCheetah-v5", "sensory"): FRESH / "dr256-HalfCheetah-v5-sensory.pt",  # 4072.3 (64 wide: 3931)
    ("dr", "HalfCheetah-v5", "physical"): FRESH / "dr256-HalfCheetah-v5-physical.pt",  # 124.2 (64 wide: 78.6)
    ("dr", "Ant-v5", "sensory"): FRESH / "dr256-Ant-v5-sensory.pt",  # 2111.9 (64 wide: 1649, one adversary)
}
MODES = ("sensory", "physical")
SEEDS = range(3)


def judge(policy: Path, seed: int) -> Path:
    return JUDGES / f"{str(policy.with_suffix('')).replace('/', '_')}-seed{seed}.pt"


def main() -> None:
    sources = {}
    for (defense, env, mode), source in CHOSEN.items():
        target = bundled_path(defense, env, mode)
        shutil.copyfile(source, target)
        sources[defense, env, mode] = source
        print(f"{target.relative_to(Path.cwd())}: {source}")
    for env in PAPER_ENVS:
        for mode in MODES:
            eps = calibrated_eps(env, mode)
            for defense in DEFENSES:
                bundled = bundled_path(defense, env, mode).relative_to(Path.cwd())
                source = sources.get((defense, env, mode), bundled)
                first = adversary_path(env, mode, defense)
                for seed in SEEDS:
                    judged = judge(source, seed)
                    out = first if seed == 0 else first.with_name(f"{first.stem}-seed{seed}.pt")
                    if trained_for(out, eps, defense, env, mode) or not trained_for(judged, eps, defense, env, mode):
                        continue  # one in place is kept (the DAgger learner's seed 0 is the attack table's)
                    shutil.copyfile(judged, out)
                    print(f"{out.relative_to(Path.cwd())}: {judged}")


if __name__ == "__main__":
    main()
