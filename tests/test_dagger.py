import json
from pathlib import Path

import numpy as np
import pytest
import torch

from aril_ros.dagger import train_learner
from aril_ros.learner_config import LearnerConfig
from aril_ros.policy import load_policy


def quiet(*args, **kwargs):
    pass


def small(tmp_path, **overrides):
    fields = dict(env="Swimmer-v5", rounds=2, episodes=1, epochs=2, eval_episodes=1, run_dir=str(tmp_path / "run"),
                  out=str(tmp_path / "out.pt"))
    return LearnerConfig(**{**fields, **overrides})


@pytest.mark.slow
def test_rounds_aggregate_the_learners_own_states_and_select_the_best(tmp_path):
    out = train_learner(small(tmp_path), log=quiet)
    state = json.loads((tmp_path / "run" / "state.json").read_text())
    assert [r["round"] for r in state["rounds"]] == [0, 1, 2]
    assert [r.get("samples") for r in state["rounds"]] == [1000, 2000, None]  # the last round only evaluates
    with np.load(tmp_path / "run" / "data.npz") as data:
        assert list(np.bincount(data["round"])) == [1000, 1000]
        # round 1's observations are the states pi_1 visited, not the expert's
        assert not np.allclose(data["obs"][1000:1100], data["obs"][:100])
    policy = load_policy(out, "Swimmer-v5")
    best = max(state["rounds"][1:], key=lambda r: r["return"])
    assert policy.meta.provenance["selected"] == f"pi_{best['round']}"
    assert policy.meta.provenance["algorithm"] == "dagger"
    assert policy.meta.provenance["command"].startswith("aril train-learner algorithm:=dagger env:=Swimmer-v5")


@pytest.mark.slow
def test_an_interrupted_run_resumes_from_its_last_round_and_ends_as_an_uninterrupted_one(tmp_path):
    train_learner(small(tmp_path / "a"), log=quiet)

    def interrupt_after_round_1(message, **kwargs):
        if "round 1:" in message:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_learner(small(tmp_path / "b"), log=interrupt_after_round_1)
    messages = []
    train_learner(small(tmp_path / "b"), log=lambda m, **k: messages.append(m))
    assert messages[0].endswith("resuming after round 1")
    assert not any("round 0:" in m or "round 1:" in m for m in messages)
    for name in ("obs", "expert_action", "round"):
        with np.load(tmp_path / "a" / "run" / "data.npz") as a, np.load(tmp_path / "b" / "run" / "data.npz") as b:
            np.testing.assert_array_equal(a[name], b[name])
    a = load_policy(tmp_path / "a" / "out.pt")
    b = load_policy(tmp_path / "b" / "out.pt")
    obs = np.random.default_rng(0).standard_normal((5, 8))
    np.testing.assert_array_equal(a.act(obs), b.act(obs))


@pytest.mark.slow
def test_more_rounds_extend_a_finished_run(tmp_path):
    train_learner(small(tmp_path), log=quiet)
    train_learner(small(tmp_path, rounds=3), log=quiet)
    state = json.loads((tmp_path / "run" / "state.json").read_text())
    assert [r.get("samples") for r in state["rounds"]] == [1000, 2000, 3000, None]


@pytest.mark.slow
def test_a_run_directory_refuses_other_settings(tmp_path):
    train_learner(small(tmp_path), log=quiet)
    with pytest.raises(ValueError, match=r"other settings \(episodes\)"):
        train_learner(small(tmp_path, episodes=2), log=quiet)


@pytest.mark.slow
def test_domain_randomisation_collects_through_random_perturbations(tmp_path):
    train_learner(small(tmp_path, algorithm="dr", mode="sensory", eps=0.05), log=quiet)
    state = json.loads((tmp_path / "run" / "state.json").read_text())
    assert "clean_return" in state["rounds"][1]
    policy = load_policy(tmp_path / "out.pt")
    assert policy.meta.provenance["algorithm"] == "dr"
    assert "sensory, random eps 0.05" in policy.meta.provenance["selection"]


def test_bad_arguments_are_refused(tmp_path):
    with pytest.raises(ValueError, match="eps:= must be > 0"):
        train_learner(small(tmp_path, algorithm="dr", eps=-0.1), log=quiet)
    with pytest.raises(ValueError, match="mode:=sensory or mode:=physical"):
        train_learner(small(tmp_path, algorithm="aril", mode="clean"), log=quiet)
    with pytest.raises(ValueError, match="unknown algorithm 'dagr'"):
        train_learner(small(tmp_path, algorithm="dagr"), log=quiet)
    with pytest.raises(ValueError, match="rounds"):
        train_learner(small(tmp_path, rounds=0), log=quiet)


@pytest.mark.slow
def test_dr_takes_the_calibrated_eps_by_default(tmp_path):
    from aril_ros.registry import calibrated_eps

    train_learner(small(tmp_path, algorithm="dr", mode="physical", rounds=1), log=quiet)
    assert load_policy(tmp_path / "out.pt").meta.provenance["eps"] == calibrated_eps("Swimmer-v5", "physical")
    (tmp_path / "cal.json").write_text('{"rows": []}')
    with pytest.raises(ValueError, match="no calibrated eps for Swimmer-v5 physical .*pass eps:="):
        calibrated_eps("Swimmer-v5", "physical", tmp_path / "cal.json")


@pytest.mark.slow
def test_dart_collects_with_the_expert_and_noise_sized_by_the_learner(tmp_path):
    train_learner(small(tmp_path, algorithm="dart"), log=quiet)
    state = json.loads((tmp_path / "run" / "state.json").read_text())
    first = state["rounds"][1]
    assert first["noise_trace"] > 0 and "collected_return" in first
    with np.load(tmp_path / "run" / "data.npz") as data:
        assert list(np.bincount(data["round"])) == [1000, 1000]


@pytest.mark.slow
def test_rounds_through_the_ros_graph_give_the_in_process_data_set(tmp_path):
    common = dict(algorithm="dr", mode="sensory", eps=0.05, rounds=2)  # round 1 collects under the attack
    train_learner(small(tmp_path / "inprocess", **common), log=quiet)
    train_learner(small(tmp_path / "graph", source="graph", **common), log=quiet)
    with np.load(tmp_path / "inprocess" / "run" / "data.npz") as a, np.load(tmp_path / "graph" / "run" / "data.npz") as b:
        for name in ("obs", "expert_action", "episode", "round"):
            np.testing.assert_array_equal(a[name], b[name])
        assert str(b["source"][0]).endswith("round-0.mcap") and str(b["source"][-1]).endswith("round-1.mcap")
    assert (tmp_path / "graph" / "run" / "round-2.mcap").exists()
    a = json.loads((tmp_path / "inprocess" / "run" / "state.json").read_text())["rounds"]
    b = json.loads((tmp_path / "graph" / "run" / "state.json").read_text())["rounds"]
    assert [r["return"] for r in a] == pytest.approx([r["return"] for r in b], rel=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["sensory", "physical"])
def test_aril_trains_an_adversary_against_each_learner_and_collects_under_it(tmp_path, mode):
    from aril_ros.adversary import load_adversary

    train_learner(small(tmp_path, algorithm="aril", mode=mode, eps=0.05, rounds=2, adversary_steps=600,
                        warm_start=True), log=quiet)
    run = tmp_path / "run"
    state = json.loads((run / "state.json").read_text())
    assert [r["round"] for r in state["rounds"]] == [0, 1, 2] and "clean_return" in state["rounds"][1]
    for r in (1, 2):  # f_r against pi_r; with warm_start, f_2 starts from f_1
        provenance = load_adversary(run / f"adversary-{r}.pt", "Swimmer-v5", mode).meta["provenance"]
        assert provenance["victim"] == str(run / f"pi-{r}.pt")
        assert (f"init:={run / 'adversary-1.pt'}" in provenance["command"]) == (r == 2)
    data = np.load(run / "data.npz")
    attacked = data["round"] == 1
    assert attacked.sum() == 1000 and (data["round"] == 0).sum() == 1000
    policy = load_policy(tmp_path / "out.pt")
    assert policy.meta.provenance["algorithm"] == "aril"
    assert f"{mode}, aril_a eps 0.05" in policy.meta.provenance["selection"]


@pytest.mark.slow
def test_aril_keeps_the_strongest_of_its_round_candidates_and_reuses_finished_ones(tmp_path):
    from aril_ros.adversary import load_adversary

    cfg = small(tmp_path, algorithm="aril", mode="physical", eps=0.05, rounds=1, adversary_steps=16_384,
                adversary_seeds=3)
    train_learner(cfg, log=quiet)
    run = tmp_path / "run"
    candidates = [load_adversary(run / f"adversary-1-seed{k}.pt").meta["provenance"] for k in range(3)]
    assert len({c["seed"] for c in candidates}) == 3  # three trainings, each its own seed
    objectives = [c["final_episode_loss"] for c in candidates]  # 16 envs x 1024 steps: each finished episodes
    assert len(set(objectives)) == 3
    chosen = load_adversary(run / "adversary-1.pt").meta["provenance"]
    assert chosen["seed"] == candidates[int(np.argmax(objectives))]["seed"]
    # killed after the candidates, before round 1 was recorded: the round runs again and trains none of them anew
    state = json.loads((run / "state.json").read_text())
    (run / "state.json").write_text(json.dumps({**state, "rounds": state["rounds"][:1]}))
    stamps = [(run / f"adversary-1-seed{k}.pt").stat().st_mtime_ns for k in range(3)]
    train_learner(cfg, log=quiet)
    assert [(run / f"adversary-1-seed{k}.pt").stat().st_mtime_ns for k in range(3)] == stamps
    with pytest.raises(ValueError, match="adversary_seeds:= must be >= 1"):
        train_learner(small(tmp_path, algorithm="aril", mode="physical", eps=0.05, adversary_seeds=0), log=quiet)



@pytest.mark.slow
@pytest.mark.xdist_group("ray")  # with the other Ray tests (tests/test_sweep.py)
def test_round_candidates_on_a_local_ray_are_the_files_trained_in_process(tmp_path, monkeypatch):
    """workers:=2 trains a round's candidates as Ray tasks side by side; each candidate is the very adversary the
    in-process run trains (same weights), and its provenance names the victim by the run's relative path."""
    from aril_ros.adversary import load_adversary

    monkeypatch.chdir(tmp_path)  # relative run directories, as the scripts use
    files = {}
    for workers in (1, 2):
        cfg = LearnerConfig(env="Swimmer-v5", algorithm="aril", mode="physical", eps=0.05, rounds=1, episodes=1,
                            epochs=2, eval_episodes=1, adversary_steps=4096, adversary_seeds=2, workers=workers,
                            run_dir=f"run{workers}", out=f"out{workers}.pt")
        train_learner(cfg, log=quiet)
        files[workers] = [load_adversary(Path(f"run{workers}/adversary-1-seed{k}.pt")) for k in range(2)]
    for alone, side_by_side in zip(files[1], files[2]):
        for name, weights in alone.state_dict().items():
            assert torch.equal(weights, side_by_side.state_dict()[name]), name
        assert side_by_side.meta["provenance"]["victim"] == "run2/pi-1.pt"
    assert files[2][0].meta["provenance"]["seed"] != files[2][1].meta["provenance"]["seed"]
    # side by side the candidates overlap on the clock; the learner's CPU time counts each training's own
    made = load_policy(Path("out2.pt")).meta.provenance
    trainings = sum(f.meta["provenance"]["train_seconds"] for f in files[2])
    assert made["rounds_log"][1]["adversary_cpu_seconds"] == pytest.approx(trainings)
    assert made["cpu_seconds"] == pytest.approx(made["train_seconds"] + trainings
                                                - made["rounds_log"][1]["adversary_seconds"], abs=0.2)

@pytest.mark.slow
def test_query_attacks_compete_with_the_trained_adversaries_for_f_t(tmp_path):
    """round_attacks:= judges the trained adversary and each query attack by pi_t's disagreement with the expert
    on the same episodes; the largest is f_t, and the round collects under it."""
    import re

    lines = []
    cfg = small(tmp_path, algorithm="aril", mode="sensory", eps=0.3, rounds=1, adversary_steps=4096,
                round_attacks="spsa,random")
    train_learner(cfg, log=lambda *a, **k: lines.append(str(a[0]) if a else ""))
    chosen = next(line for line in lines if "f_1 is" in line)
    objectives = dict(re.findall(r"(aril_a adversary-1-seed0\.pt|spsa|random) (-?[0-9.]+)",
                                 chosen.split("objectives")[1]))
    assert set(objectives) == {"aril_a adversary-1-seed0.pt", "spsa", "random"}
    strongest = max(objectives, key=lambda label: float(objectives[label]))
    assert f"f_1 is {strongest} (" in chosen
    record = json.loads((tmp_path / "run" / "state.json").read_text())["rounds"][1]
    assert record.get("attack", "aril_a") == strongest.split()[0]
    assert (tmp_path / "run" / "adversary-1.pt").exists() == (strongest.split()[0] == "aril_a")
    with pytest.raises(ValueError, match="black-box attacks"):
        train_learner(small(tmp_path, algorithm="aril", round_attacks="fgsm_k"), log=quiet)
    with pytest.raises(ValueError, match="without warm_start"):
        train_learner(small(tmp_path, algorithm="aril", round_attacks="spsa", warm_start=True), log=quiet)


@pytest.mark.slow
def test_mixed_rounds_collect_under_each_attack_and_select_by_the_worst(tmp_path):
    """mix:= has pi_r also collect under each named attack on the round's own env seeds, every pair aggregated and
    each return recorded; select:=worst returns the learner whose worst return over f_r and them is best, and a
    finished run can be selected again by another rule without collecting anything."""
    import dataclasses

    from aril_ros import collectors, seeds

    seen = []

    def counting(run, r, learner, spec):
        seen.append((r, spec.mode, spec.attack, spec.eps, spec.seed))
        return collectors.engine(run, r, learner, spec)

    cfg = small(tmp_path, algorithm="dr", mode="sensory", eps=0.05, mix="clean,fgsm_k", select="worst")
    out = train_learner(cfg, log=quiet, collector=counting)
    assert seen == [(0, "clean", "none", 0.0, seeds.collection(0, 0))] + [
        call for r in (1, 2) for call in ((r, "sensory", "random", 0.05, seeds.collection(0, r)),
                                          (r, "clean", "none", 0.0, seeds.collection(0, r)),
                                          (r, "sensory", "fgsm_k", 0.05, seeds.collection(0, r)))]
    rounds = json.loads((tmp_path / "run" / "state.json").read_text())["rounds"]
    assert [sorted(r.get("mix", {})) for r in rounds] == [[], ["clean", "fgsm_k"], ["clean", "fgsm_k"]]
    with np.load(tmp_path / "run" / "data.npz") as data:
        assert list(np.bincount(data["round"])) == [1000, 3000]  # round 1: under noise, clean and under FGSM^k
    worst = {r["round"]: min(r["return"], *r["mix"].values()) for r in rounds[1:]}
    provenance = load_policy(out).meta.provenance
    assert provenance["selected"] == f"pi_{max(worst, key=worst.get)}"
    assert "best worst return" in provenance["selection"] and "clean,fgsm_k" in provenance["selection"]

    seen.clear()  # the same run selected by the paper's rule: nothing collected again
    again = train_learner(dataclasses.replace(cfg, select="own", out=str(tmp_path / "own.pt")), log=quiet,
                          collector=counting)
    own = max(rounds[1:], key=lambda r: r["return"])["round"]
    assert seen == [] and load_policy(again).meta.provenance["selected"] == f"pi_{own}"
    for bad, match in ((dict(mix="fgsm_k,teleport"), "mix:= takes"), (dict(select="worst"), "name them in mix"),
                       (dict(algorithm="dagger", mix="random"), "dr's and aril's rounds"),
                       (dict(select="best"), "select:= must be")):
        with pytest.raises(ValueError, match=match):
            train_learner(small(tmp_path / "bad", **{"algorithm": "dr", "mode": "sensory", **bad}), log=quiet)


def test_the_rounds_collect_with_the_collector_they_are_given(tmp_path):
    """A collector passed in runs every round, each as its RoundSpec says (round 0: the expert, clean), and its own
    figures go into the round's record."""
    import dataclasses

    from aril_ros import collectors, seeds

    seen = []

    def counting(run, r, learner, spec):
        seen.append((r, spec.mode, spec.attack, spec.eps, spec.seed, spec.policy))
        return dataclasses.replace(collectors.engine(run, r, learner, spec), figures={"collected_by": "counting"})

    train_learner(small(tmp_path, algorithm="dr", mode="sensory", eps=0.05, seed=1), log=quiet, collector=counting)
    run = tmp_path / "run"
    assert seen == [(0, "clean", "none", 0.0, seeds.collection(1, 0), "expert")] + [
        (r, "sensory", "random", 0.05, seeds.collection(1, r), str(run / f"pi-{r}.pt")) for r in (1, 2)]
    rounds = json.loads((run / "state.json").read_text())["rounds"]
    assert [r["collected_by"] for r in rounds] == ["counting"] * 3


def test_the_bundled_learners_commands_name_their_arguments_in_the_configs_order():
    """LearnerConfig is made of parts; its arguments keep the order every bundled learner's command names them in,
    and each command parses back to the settings its file records."""
    import dataclasses

    from aril_ros.args import parse_args
    from aril_ros.provenance import settings_of
    from aril_ros.registry import DATA_DIR

    order = [f.name for f in dataclasses.fields(LearnerConfig)]
    files = [f for name in ("dagger", "dart", "dr", "aril") for f in sorted((DATA_DIR / name).glob("*.pt"))]
    assert len(files) == 18
    for file in files:
        provenance = load_policy(file).meta.provenance
        words = provenance["command"].split()[2:]
        keys = [word.split(":=")[0] for word in words]
        assert keys == sorted(keys, key=order.index), file
        assert parse_args(LearnerConfig, words) == settings_of(provenance, LearnerConfig), file


@pytest.mark.slow
@pytest.mark.parametrize("algorithm, mode", [("dr", "clean"), ("aril", "clean"), ("aril", "sensory")])
def test_a_timing_budget_in_the_loop_times_each_round_as_its_algorithm_says(tmp_path, algorithm, mode):
    """dr's rounds are timed at random, aril's by a timing adversary trained against the round's learner (beside its
    value adversary in mode sensory: the joint budget); each round's pairs are what the learner saw under that timing
    (replayed on the engine from the files the round used), labelled on the true state."""
    from aril_ros import seeds
    from aril_ros.attacks import make_attack
    from aril_ros.envs import layout_of
    from aril_ros.policy import resolve_policy
    from aril_ros.rollout import RolloutEngine
    from aril_ros.sweep import digest_of
    from aril_ros.timing import TimingAttack, TimingBudget
    from aril_ros.timing_adversary import load_timing_adversary

    cfg = small(tmp_path, algorithm=algorithm, mode=mode, eps=0.05, delay=2, drop=0.2, adversary_steps=2048)
    out = train_learner(cfg, log=quiet)
    run = tmp_path / "run"
    timing_file = run / "timing-adversary-1.pt"
    assert timing_file.exists() == (algorithm == "aril")
    if algorithm == "aril":  # trained against pi_1 for the run's budget
        made = load_timing_adversary(timing_file)
        assert made.budget == {"delay": 2, "drop": 0.2, "action_delay": 0}
        assert made.meta["provenance"]["victim_sha256"] == digest_of((run / "pi-1.pt").read_bytes())
    assert (run / "adversary-1.pt").exists() == (algorithm == "aril" and mode == "sensory")
    chooser = "learned" if algorithm == "aril" else "random"
    attack = {"clean": "none", "sensory": "aril_a" if algorithm == "aril" else "random"}[mode]
    layout = layout_of("Swimmer-v5")
    learner, expert = load_policy(run / "pi-1.pt"), resolve_policy("expert", "Swimmer-v5")
    engine = RolloutEngine("Swimmer-v5", learner, expert,
                           make_attack(attack, layout, 0.05, victim=learner, expert=expert,
                                       adversary=str(run / "adversary-1.pt") if attack == "aril_a" else None,
                                       mode=mode),
                           mode, n_envs=1, timing=TimingAttack(TimingBudget(2, 0.2), chooser,
                                                               str(timing_file) if chooser == "learned" else ""))
    traj = engine.rollout(1, seeds.collection(0, 1))
    engine.close()
    assert traj.timing[0, :, 0].max() >= 1 and traj.timing[0, :, 1].sum() >= 1  # late and dropped observations
    with np.load(run / "data.npz") as data:
        np.testing.assert_array_equal(data["obs"][data["round"] == 1], traj.obs[0, : traj.length[0]])
        np.testing.assert_array_equal(data["expert_action"][data["round"] == 1],
                                      traj.expert_action[0, : traj.length[0]])
    provenance = load_policy(out).meta.provenance
    assert provenance["timing"] == {"delay": 2, "drop": 0.2, "action_delay": 0, "chooser": chooser}
    assert f"timed by {chooser} within delay 2, drop 0.2" in provenance["selection"]
    state = json.loads((run / "state.json").read_text())
    assert "clean_return" in state["rounds"][1]
    with pytest.raises(ValueError, match="a timing budget .* is played in dr's and aril's loops; dagger collects clean"):
        train_learner(small(tmp_path / "x", delay=1), log=quiet)
