import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from aril_ros.policy import load_weights
from aril_ros.provenance import cpu
from aril_ros.registry import THREATS, bundled_file
from aril_ros.report import ReportConfig, build_report
from aril_ros.report.stats import summarise, t95, worst_attack
from aril_ros.report.tables import table_markdown
from aril_ros.report.text import _budgets
from tests.conftest import local_ray


def quiet(*args, **kwargs):
    pass


def test_intervals_are_over_seed_means_when_there_are_several_seeds():
    one = summarise([[1.0, 2.0, 3.0, 4.0]])
    assert one["ci_over"] == "episodes" and one["mean"] == 2.5
    assert one["ci95"] == pytest.approx(t95(3) * np.std([1, 2, 3, 4], ddof=1) / 2)
    three = summarise([[10.0, 10.0], [20.0, 20.0], [30.0, 30.0]])
    assert three["ci_over"] == "seeds" and three["mean"] == 20.0
    assert three["ci95"] == pytest.approx(4.303 * 10.0 / np.sqrt(3))  # t(2) * sd of the seed means / sqrt(3)
    assert t95(25) == 2.086  # the nearest tabled df below: a slightly wider interval, never a narrower one


def test_one_producer_of_cells_gives_numpys_figures_and_one_rule_picks_the_worst_attack():
    returns = [3.0, 7.5, -1.25, 10.0, 4.0]
    cell = summarise([returns])
    assert cell["mean"] == np.mean(returns) and cell["std"] == np.std(returns)  # the std aril eval prints (ddof 0)
    assert cell["median"] == 4.0 and (cell["seeds"], cell["episodes"]) == (1, 5)
    two = summarise([[1.0, 3.0], [5.0, 11.0]])
    assert two["mean"] == 5.0 and two["std"] == np.std([1, 3, 5, 11])  # mean of seed means; std over all episodes
    cells = {"none": {"mean": 100.0}, "random": {"mean": 90.0}, "fgsm": {"mean": 40.0}, "fgsm_k": {"mean": 40.0},
             "aril_a": {"mean": 55.0}}
    assert worst_attack(cells) == "fgsm"  # the lowest mean among the threats; a tie goes to the first in THREATS
    assert "none" not in THREATS and worst_attack({"none": {"mean": 0.0}, "aril_a": {"mean": 1.0}}) == "aril_a"
    assert worst_attack(cells, among=("random", "aril_a")) == "aril_a" and worst_attack({}) is None


def test_the_top_two_defenses_are_compared_seed_by_seed_and_unseparated_cells_named():
    """A cell's top two by their worst attack; the first's lead as the difference of their returns seed by seed,
    with a Student-t interval over seeds; a cell is separated only when that interval leaves 0 out (one seed never
    is), and the report names the cells that are not."""
    from aril_ros.report import Evaluated, leads
    from aril_ros.report.jobs import Key
    from aril_ros.report.stats import paired_difference
    from aril_ros.report.text import leads_lines

    lead = paired_difference({0: 110.0, 1: 130.0, 2: 120.0}, {0: 100.0, 1: 110.0, 2: 120.0})
    assert lead["difference"] == 10.0 and lead["seeds"] == [0, 1, 2]
    assert lead["ci95"] == pytest.approx(4.303 * 10.0 / np.sqrt(3)) and not lead["separated"]  # [-14.8, 34.8]
    assert paired_difference({0: 110.0, 1: 131.0}, {0: 100.0, 1: 120.0, 2: 0.0})["separated"]  # seeds 0, 1: 10, 11
    assert not paired_difference({0: 200.0}, {0: 100.0})["separated"]  # one seed: no interval

    def evaluated(returns_of):  # every defense clean and under every threat, per seed, one episode each
        plan, returns = [], []
        for (env, defense, seed), worst in returns_of.items():
            for attack in ("none", *THREATS):
                plan.append((Key(env, "physical", defense, attack, 0.0 if attack == "none" else 1.0, seed), {}))
                returns.append([worst if attack == "aril_a" else worst + 100.0])
        return Evaluated({}, {}, {}, {}, plan, returns, {}, [])

    seeds = (0, 1, 2)
    done = evaluated({**{("Swimmer-v5", "dr", s): 50.0 + s for s in seeds},  # DR leads ARIL by 40 on every seed
                      **{("Swimmer-v5", "aril", s): 10.0 + s for s in seeds},
                      **{("Swimmer-v5", "gail", s): -5.0 for s in seeds},
                      **{("Ant-v5", "aril", s): [900.0, 1500.0, 700.0][s] for s in seeds},  # ARIL first by 33 on
                      **{("Ant-v5", "dr", s): [1000.0, 1000.0, 1000.0][s] for s in seeds}})  # average, not separated
    top = leads(done, ["Swimmer-v5", "Ant-v5"], ["physical"])
    swimmer, ant = top[("Swimmer-v5", "physical")], top[("Ant-v5", "physical")]
    assert (swimmer["first"], swimmer["second"], swimmer["difference"], swimmer["separated"]) == ("dr", "aril", 40.0,
                                                                                                   True)
    assert swimmer["first_mean"] == 51.0 and swimmer["ci95"] == 0.0
    assert (ant["first"], ant["second"], ant["separated"]) == ("aril", "dr", False)
    assert ant["difference"] == pytest.approx(100.0 / 3)
    text = "\n".join(leads_lines({"top_two": {f"{e} {m}": v for (e, m), v in top.items()}}))
    assert "| Swimmer-v5 physical | DR (51) | ARIL (11) | +40 [+40, +40] | 3 | yes |" in text
    assert "cannot separate the top two in 1 of 2 cells: Ant-v5 physical (ARIL or DR)." in text


@pytest.mark.slow
def test_attack_and_defense_tables_print_the_same_cells_as_the_report(tmp_path, monkeypatch):
    from aril_ros import experiments
    from aril_ros.report.tables import table_cells

    returns = {"none": [100.0, 104.0], "random": [90.0, 80.0], "fgsm": [50.0, 70.0], "fgsm_k": [61.0, 57.0],
               "spsa": [66.0, 62.0], "aril_a": [75.0, 65.0]}
    monkeypatch.setattr(experiments, "evaluate_all", lambda jobs, *a, **k: [
        {"returns": returns[job["attack"] or "none"], "eps": job["eps"], "mean_expert_loss": 0.0} for job in jobs])
    trained = []
    monkeypatch.setattr(experiments, "ready_adversaries", lambda wanted, *a, **k: trained.extend(wanted))
    monkeypatch.setattr(experiments, "load_adversary", lambda path: type("A", (), {"meta": {"provenance": {}}}))
    payload = experiments.defense_table(experiments.DefenseTableConfig(envs="Swimmer-v5", defenses="aril",
                                                                       out=str(tmp_path / "def")), log=quiet)
    ours = payload["rows"][0]["cells"]["aril"]
    # the adversary is trained against the defense by its bundled name, so a task on any node finds it
    assert [(w.victim, w.seed, Path(w.out).name) for w in trained] == [("aril", 0, "Swimmer-v5-sensory-aril.pt")]
    report = table_cells({("Swimmer-v5", "sensory", "aril", a, 0.0 if a == "none" else 1.0): [r]
                          for a, r in returns.items()}, "Swimmer-v5", "sensory")[("aril", "worst")]
    assert ours["worst"] == report["attack"] == "fgsm_k"
    assert (ours["mean"], ours["std"], ours["clean"]) == (report["mean"], report["std"], report["clean"])
    assert (ours["mean"], ours["std"], ours["clean"]) == (59, 2, 102)
    assert "| ARIL | 59 ± 2 (-42.2%, FGSM^k) | -42.2% |" in (tmp_path / "def.md").read_text()


def test_a_cell_that_could_not_be_produced_says_why():
    cells = {"Swimmer-v5": {("dagger", "none"): {"mean": 100.0, "ci95": 1.0}}}
    missing = {("policy", "gail", "Swimmer-v5", "sensory", 0): "no bundled gail for Swimmer-v5"}
    lines, overall = table_markdown("sensory", ["Swimmer-v5"], cells, {"Swimmer-v5": 0.3}, missing)
    gail = next(line for line in lines if line.startswith("| GAIL |"))
    assert "missing: no bundled gail for Swimmer-v5" in gail and overall[("gail", "worst")] is None
    assert "| DAgger, clean | 100 ± 1 | 81 |" in lines[2]


@pytest.mark.slow
def test_the_report_is_built_from_its_evaluations_and_resumes_from_the_cache(tmp_path):
    cfg = ReportConfig(envs="Swimmer-v5", modes="physical", episodes=2, sweep_episodes=1, horizon=40, perf=False,
                       work_dir=str(tmp_path / "work"), out=str(tmp_path / "docs" / "results.md"))
    with local_ray():  # one Ray for both builds, each of which would start its own
        logged = []
        out = build_report(cfg, log=lambda *a, **k: logged.append(a[0]))
        text = out.read_text()
        figures = tmp_path / "docs" / "results"
        payload = json.loads((figures / "report.json").read_text())
        # 5 defenses x (clean + 5 attacks + 5 sweep attacks x 2 scales), and DAgger under the 3 black-box rows
        assert len(payload["evaluations"]) == 5 * (6 + 5 * 2) + 3
        for row in ("DAgger, clean", "FGSM (on DAgger)", "FGSM^k (on DAgger)", "ARIL-A (on DAgger)",
                    "FGSM^k on a surrogate (on DAgger)", "ARIL-A + search (on DAgger)", "ARIL-A, directed (on DAgger)",
                    "GAIL", "DR", "DART", "ARIL"):
            assert f"| {row} |" in text
        # the black-box rows: a surrogate fitted here (the bundled one is for 1000-step episodes), and search
        jobs = {e["key"]["attack"]: e["job"] for e in payload["evaluations"]
                if e["key"]["defense"] == "dagger" and e["key"]["scale"] == 1.0}
        assert jobs["transfer"]["attack_file"].endswith("surrogates/Swimmer-v5-physical-dagger-seed0.pt")
        assert jobs["aril_a_search"] == {**jobs["aril_a"], "search": 16}
        assert jobs["aril_a_directed"]["attack_file"].endswith("aril_ros/data/directed-adversary/Swimmer-v5-physical.pt")
        assert "The strongest black-box attack" in text and "takes at least as much as white-box FGSM^k in" in text
        assert "## Table 2: physical attacks" in text and "Swimmer-v2 paper" in text
        assert "Ant's contact-force" not in text
        assert "| Swimmer-v5 physical seed 0 | 10 | pi_8 | 1,000,000 steps per round, fresh each round, the strongest of 3 |" in text
        assert (figures / "sweep-Swimmer-v5-physical.png").stat().st_size > 10_000
        assert (figures / "aril-rounds.png").exists() and "results/aril-rounds.png" in text
        # every table figure is the mean of the episodes recorded in the JSON
        dagger_clean = next(e for e in payload["evaluations"]
                            if e["key"]["defense"] == "dagger" and e["key"]["attack"] == "none")
        assert f"| DAgger, clean | {np.mean(dagger_clean['returns']):.0f} ±" in text
        assert payload["files"]["aril_ros/data/dagger/Swimmer-v5.pt"] and payload["command"].startswith("aril report")
        # the cache is committed (benchmarks/scripts/full-protocol.sh): bundled files by their path in the checkout
        cached_policies = {json.loads(f.read_text())["job"]["policy"] for f in (tmp_path / "work" / "cache").glob("*.json")}
        assert "aril_ros/data/dagger/Swimmer-v5.pt" in cached_policies
        assert not any(Path(p).is_absolute() and not p.startswith(str(tmp_path)) for p in cached_policies)
        # the CPU the evaluations ran on (another model gives other returns from the same files)
        assert payload["evaluated_on"] == {cpu(): 83} and f"; evaluated on {cpu()} (another MuJoCo" in text
        # the compute: every distinct evaluation timed, the bundled files' trainings from their provenance
        stages = payload["compute"]["stages"]
        assert stages["evaluations"] == {**stages["evaluations"], "tasks": 83, "untimed": 0}
        assert stages["evaluations"]["cpu_hours"] > 0 and stages["adversary trainings"]["tasks"] == 5 + 1
        hours = payload["compute"]["hours_on_cores"]
        assert hours["1"] >= hours["2"] >= hours["128"] > 0 and "- Compute: " in text
        logged.clear()
        build_report(cfg, log=lambda *a, **k: logged.append(a[0]))
        assert any(f"83 evaluations: 83 cached on this CPU model ({cpu()}), 0 to run" in line for line in logged)
        assert "distinct evaluations" not in text and "0 of 83 distinct evaluations run here" in out.read_text()
        assert out.read_text().split("## Protocol")[1] == text.split("## Protocol")[1]  # only the stamp changes


def test_the_evaluation_cache_serves_only_the_cpu_model_it_was_made_on(tmp_path, monkeypatch):
    """An evaluation is cached under the CPU model it ran on: the same model reads it back, another evaluates again
    (its kernels give other returns from the same files) and keeps its own beside it."""
    from aril_ros.report import jobs

    job = {"env": "Swimmer-v5", "policy": str(bundled_file("dagger", "Swimmer-v5")), "mode": "clean", "attack": "none",
           "eps": 0.0, "attack_file": "", "rescale": False, "episodes": 1, "seed": 3000, "horizon": 5}
    returns, counts, runs = jobs.run_jobs([job], tmp_path, 1, "", False, quiet)
    assert counts == {"run": 1, "cached": 0} and runs[0]["cpu"] == cpu()
    assert jobs.run_jobs([job], tmp_path, 1, "", False, quiet)[:2] == (returns, {"run": 0, "cached": 1})
    monkeypatch.setattr(jobs, "cpu", lambda: "Another CPU (AVX9)")
    assert jobs.run_jobs([job], tmp_path, 1, "", False, quiet)[1] == {"run": 1, "cached": 0}
    kept = sorted(json.loads(f.read_text())["cpu"] for f in tmp_path.glob("*.json"))
    assert kept == sorted([cpu(), "Another CPU (AVX9)"])
    assert jobs.run_jobs([job], tmp_path, 1, "", False, quiet)[1] == {"run": 0, "cached": 1}


def test_bad_report_arguments_are_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown budget"):
        build_report(ReportConfig(budget="huge"), log=quiet)
    with pytest.raises(ValueError, match="multiples other than 0 and 1"):
        build_report(ReportConfig(sweep_scales="0.5,1", perf=False, out=str(tmp_path / "r.md")), log=quiet)


def test_other_training_seeds_repeat_the_bundled_policys_own_command(tmp_path, monkeypatch):
    from aril_ros import dagger
    from aril_ros.report.artifacts import Artifacts

    seen = []

    def train(cfg, log):  # stands in for training: its run directory as a real one leaves it, and the file
        seen.append(cfg)
        Path(cfg.run_dir).mkdir(parents=True)
        (Path(cfg.run_dir) / "data.npz").write_bytes(b"the aggregated data set")
        return cfg.out

    monkeypatch.setattr(dagger, "train_learner", train)
    store = Artifacts(tmp_path, workers=1, address="", adversary_steps=1000, log=quiet)  # in this process: training is patched
    out = store.policies([("aril", "Swimmer-v5", "physical", 2)])[("aril", "Swimmer-v5", "physical", 2)]
    bundled = load_weights(bundled_file("aril", "Swimmer-v5", "physical"))[0]["provenance"]
    cfg = seen[0]
    assert out == tmp_path / "policies" / "aril-Swimmer-v5-physical-seed2.pt" and cfg.seed == 2
    assert cfg.run_dir == str(tmp_path / "learners" / "aril-Swimmer-v5-physical-seed2")
    assert not Path(cfg.run_dir).exists()  # served resuming; the finished file's provenance has its rounds
    for key, value in bundled["settings"].items():  # read back from the settings, not re-parsed from the command
        if key not in ("seed", "out", "run_dir"):
            assert getattr(cfg, key) == value, key
    for word in bundled["command"].split()[2:]:  # which say what the command says
        key, value = word.split(":=")
        if key not in ("seed", "out", "run_dir"):
            assert str(getattr(cfg, key)) == value, key


@pytest.mark.slow
def test_several_training_seeds_give_intervals_over_seeds(tmp_path, monkeypatch):
    import shutil

    from aril_ros import dagger, gail

    written = []

    def copy_bundled(algorithm):  # stands in for training: seed 1 starts as a copy of seed 0
        def train(cfg, log):
            written.append(Path(cfg.out).name)
            name = "gail" if algorithm == "gail" else cfg.algorithm
            if algorithm == "learner":  # a learner's training leaves its run directory
                Path(cfg.run_dir).mkdir(parents=True)
            Path(cfg.out).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(bundled_file(name, cfg.env, getattr(cfg, "mode", None)), cfg.out)
            return cfg.out
        return train

    monkeypatch.setattr(dagger, "train_learner", copy_bundled("learner"))
    monkeypatch.setattr(gail, "train_gail", copy_bundled("gail"))
    cfg = ReportConfig(envs="Swimmer-v5", modes="physical", seeds="0,1", episodes=2, sweep_episodes=1, horizon=30,
                       sweep_scales="2", sweep_attacks="random", adversary_steps=2048, perf=False,
                       workers=1, work_dir=str(tmp_path / "work"), out=str(tmp_path / "results.md"))
    build_report(cfg, log=quiet)
    payload = json.loads((tmp_path / "results" / "report.json").read_text())
    assert {e["key"]["seed"] for e in payload["evaluations"]} == {0, 1}
    seed1 = [e for e in payload["evaluations"] if e["key"]["seed"] == 1 and e["key"]["attack"] == "aril_a"]
    assert len(seed1) == 5 and all("work/adversaries" in e["job"]["attack_file"] for e in seed1)
    assert "training seeds 0, 1" in (tmp_path / "results.md").read_text()
    assert "2 training seeds" in (tmp_path / "results.md").read_text()
    # GAIL writes its best policy while it trains: only a finished training takes the name a rerun skips
    assert "gail-Swimmer-v5-seed1.partial.pt" in written
    assert sorted(p.name for p in (tmp_path / "work" / "policies").iterdir()) == [
        "aril-Swimmer-v5-physical-seed1.pt", "dagger-Swimmer-v5-seed1.pt", "dart-Swimmer-v5-seed1.pt",
        "dr-Swimmer-v5-physical-seed1.pt", "gail-Swimmer-v5-seed1.pt"]
    assert not list((tmp_path / "work" / "learners").iterdir())  # run directories go when their training ends


def test_the_performance_step_finds_benchmarks_by_entry_point_not_by_path(monkeypatch):
    from aril_ros.report import perf

    figures = perf.run_benchmark("engine", ["env:=Swimmer-v5", "steps:=200", "n_envs:=4"])
    assert figures["command"] == "python -m aril_ros.benchmarks.engine env:=Swimmer-v5 steps:=200 n_envs:=4"
    assert figures["env"] == "Swimmer-v5" and figures["raw env.step"] > 0 and figures["engine physical"] > 0
    missing = perf.run_benchmark("nowhere", [])
    assert "no aril_ros.benchmarks entry named 'nowhere'" in missing["error"]
    failed = perf.run_benchmark("engine", ["env:=CartPole-v1"])  # a benchmark that fails is recorded, not raised
    assert failed["error"] and failed["command"].startswith("python -m aril_ros.benchmarks.engine")
    ran = []
    monkeypatch.setattr(perf.plugins, "names", lambda group: ["adversary", "engine", "graph", "extra"])
    monkeypatch.setattr(perf, "run_benchmark", lambda name, args: ran.append((name, args)) or {})
    assert list(perf.run_benchmarks(1000, quiet, env="Swimmer-v5")) == ["engine", "graph", "adversary", "soak", "extra"]
    assert ran[0] == ("engine", ["env:=Swimmer-v5", "steps:=1000"]) and ran[-1] == ("extra", [])


def test_the_text_names_each_round_adversary_budget_once_with_its_runs():
    """Every seed of a run shares its settings: the comparison names a budget once, with the runs (env and mode)."""
    warm = {"adversary_steps": 500_000, "warm_start": True, "adversary_seeds": 1}
    fresh = {"adversary_steps": 1_000_000, "warm_start": False, "adversary_seeds": 3}
    curves = {"Ant-v5 sensory seed 0": warm, "Ant-v5 sensory seed 1": warm, "Ant-v5 physical seed 0": warm,
              "Swimmer-v5 physical seed 0": fresh}
    assert _budgets(curves) == ("500,000 steps per round, warm-started from the previous round's adversary: "
                                "Ant-v5 sensory, Ant-v5 physical; 1,000,000 steps per round, fresh each round, "
                                "the strongest of 3: Swimmer-v5 physical")


def test_the_report_runs_only_performance_benchmarks_with_its_own_arguments():
    """aril report's performance section runs every registered benchmark, one it has no arguments for with none: each
    benchmark this package registers must be one it knows (the verdict benchmark, hours of attacks, ran so once)."""
    from aril_ros import plugins
    from aril_ros.report.perf import GROUP, arguments

    ours = {name for name in plugins.names(GROUP) if plugins.value(GROUP, name).startswith(("aril_ros", "benchmarks."))}
    assert ours == set(arguments(1000))


def trainings_copy_the_bundled_files(monkeypatch) -> None:
    """Stand-ins for the learners' and GAIL's trainings: another seed starts as a copy of the bundled seed 0, and a
    learner's training leaves its run directory as a real one does."""
    import shutil

    from aril_ros import dagger, gail

    def copy_bundled(cfg, log):
        name = "gail" if isinstance(cfg, gail.GailConfig) else cfg.algorithm
        Path(cfg.out).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(bundled_file(name, cfg.env, getattr(cfg, "mode", None)), cfg.out)
        if not isinstance(cfg, gail.GailConfig):
            Path(cfg.run_dir).mkdir(parents=True)
        return cfg.out

    monkeypatch.setattr(dagger, "train_learner", copy_bundled)
    monkeypatch.setattr(gail, "train_gail", copy_bundled)


@pytest.mark.slow
def test_more_seeds_go_to_the_cells_the_first_seeds_cannot_separate(tmp_path, monkeypatch):
    """more_seeds:= trains and evaluates those seeds of every defense only in the cells whose top two the first
    seeds leave unseparated (one seed leaves every cell so), and the report says where."""
    trainings_copy_the_bundled_files(monkeypatch)
    cfg = ReportConfig(envs="Swimmer-v5", modes="physical", seeds="0", more_seeds="1", episodes=2, sweep_episodes=1,
                       horizon=30, sweep_scales="2", sweep_attacks="random", adversary_steps=2048, perf=False,
                       workers=1, work_dir=str(tmp_path / "work"), out=str(tmp_path / "results.md"))
    logged = []
    build_report(cfg, log=lambda *a, **k: logged.append(str(a[0]) if a else ""))
    payload = json.loads((tmp_path / "results" / "report.json").read_text())
    text = (tmp_path / "results.md").read_text()
    assert any("1 cells whose top two the seeds 0 cannot separate get seeds 1: Swimmer-v5 physical" in line
               for line in logged)
    assert payload["seeds_per_cell"] == {"Swimmer-v5 physical": [0, 1]}
    assert {e["key"]["seed"] for e in payload["evaluations"] if e["key"]["defense"] == "aril"} == {0, 1}
    lead = payload["top_two"]["Swimmer-v5 physical"]
    assert lead["seeds"] == [0, 1] and "## Which defense leads" in text
    assert "and 1 too where those could not separate a cell's top two defenses: Swimmer-v5 physical" in text


def test_evaluate_false_only_makes_the_files_the_evaluations_need(tmp_path, monkeypatch):
    """evaluate:=false (a machine whose CPU model the cache does not serve): the other seeds' policies, the ARIL-As
    against them and DAgger's surrogate and directed ARIL-A are made where the report would make them, nothing is evaluated and no report
    is written; more_seeds:=, which evaluations decide, is refused with it."""
    trainings_copy_the_bundled_files(monkeypatch)
    work, out = tmp_path / "work", tmp_path / "results.md"
    cfg = ReportConfig(budget="full", envs="Swimmer-v5", modes="physical", seeds="0,1", evaluate=False, horizon=30,
                       adversary_steps=2048, workers=1, work_dir=str(work), out=str(out))
    with pytest.raises(ValueError, match="more_seeds:= goes where the evaluations"):
        build_report(dataclasses.replace(cfg, more_seeds="2"), log=quiet)
    logged = []
    assert build_report(cfg, log=lambda *a, **k: logged.append(str(a[0]) if a else "")) is None
    defenses = ["aril", "dagger", "dart", "dr", "gail"]
    assert sorted(p.name for p in (work / "adversaries").iterdir()) == [
        f"Swimmer-v5-physical-{d}-seed1.pt" for d in defenses]
    assert len(list((work / "policies").iterdir())) == 5
    assert "Swimmer-v5-physical-dagger-seed1.pt" in [p.name for p in (work / "surrogates").iterdir()]
    assert [p.name for p in (work / "directed-adversaries").iterdir()] == ["Swimmer-v5-physical-dagger-seed1.pt"]
    assert not (work / "cache").exists() and not out.exists() and not out.with_suffix("").exists()
    assert any("evaluate:=false: 22 policy and adversary files" in line and "nothing evaluated" in line
               for line in logged)
