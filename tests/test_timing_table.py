"""aril timing-table: each defense under its worst timing attack over its training seeds, every cell kept with its
settings so that a rerun resumes, and the learned chooser beside fixed and random at its budgets."""
import dataclasses
import json

import numpy as np
import pytest

from aril_ros.timing_table import TimingTableConfig, timing_table


@pytest.mark.slow
def test_the_timing_table_takes_the_worst_chooser_over_seeds_and_resumes(tmp_path):
    from aril_ros.policy import save_policy
    from tests.conftest import random_policy

    for seed in (1, 2):  # two training seeds of a defense trained elsewhere, by the label=path form
        save_policy(random_policy("Swimmer-v5", seed=seed), tmp_path / f"mine-Swimmer-v5-seed{seed}.pt")
    save_policy(random_policy("Swimmer-v5", seed=9), tmp_path / "elsewhere-Hopper-v5-seed1.pt")  # not on Swimmer
    cfg = TimingTableConfig(envs="Swimmer-v5", defenses=f"dagger,mine={tmp_path}/mine-{{env}}-seed{{seed}}.pt,"
                                                        f"elsewhere={tmp_path}/elsewhere-{{env}}-seed{{seed}}.pt",
                            training_seeds="1,2", seed_dir=str(tmp_path), steps="1,3", kinds="delay,drop",
                            learned="drop3", learned_steps=2048, episodes=2, horizon=60, workers=1,
                            adversary_dir=str(tmp_path / "adv"), out=str(tmp_path / "timing"))
    with pytest.raises(ValueError, match=r"dagger on Swimmer-v5: no policy file .*dagger-Swimmer-v5-seed1.pt"):
        timing_table(cfg, log=lambda *a, **k: None)
    for seed in (1, 2):
        save_policy(random_policy("Swimmer-v5", seed=10 + seed), tmp_path / f"dagger-Swimmer-v5-seed{seed}.pt")
    lines = []
    payload = timing_table(cfg, log=lambda line, **_: lines.append(line))
    assert lines[0] == "[timing-table] 40 cells to run (0 kept), 4 timing adversaries wanted"
    cells = payload["cells"]
    assert len(cells) == 2 * 2 * (1 + 4 * 2 + 1)  # defenses x seeds x (clean, 4 budgets x fixed/random, 1 learned)
    row = payload["table"]["Swimmer-v5|mine"]
    for name, entry in row["budgets"].items():
        means = {c: v["mean"] for c, v in entry["choosers"].items()}
        assert entry["worst"] == min(means, key=means.get)
        assert ("learned" in means) == (name == "drop3")
        per_seed = [np.mean(cells[f"Swimmer-v5|mine|{s}|{name}-fixed"]["returns"]) for s in (1, 2)]
        assert entry["choosers"]["fixed"]["mean"] == pytest.approx(np.mean(per_seed), abs=1e-3)
    learned = cells["Swimmer-v5|mine|1|drop3-learned"]
    assert learned["timing_file"].endswith("Swimmer-v5-mine-seed1-drop3.pt")
    markdown = (tmp_path / "timing.md").read_text()
    assert "| DAgger | " in markdown and "| mine | " in markdown and "observations dropped 0.3*" in markdown
    assert "Not on Swimmer-v5 (no policy file of it there): elsewhere." in markdown
    assert (tmp_path / "timing-Swimmer-v5.png").is_file() and "](timing-Swimmer-v5.png)" in markdown
    assert "keeps the most return in" in markdown and "the learned timing adversary is the worst chooser" in markdown
    # a rerun keeps every cell; more episodes run every cell again
    lines.clear()
    timing_table(cfg, log=lambda line, **_: lines.append(line))
    assert lines[0] == "[timing-table] 0 cells to run (40 kept), 4 timing adversaries wanted"
    assert json.loads((tmp_path / "timing.json").read_text())["cells"] == cells
    lines.clear()
    timing_table(dataclasses.replace(cfg, episodes=3), log=lambda line, **_: lines.append(line))
    assert lines[0] == "[timing-table] 40 cells to run (40 kept), 4 timing adversaries wanted"


def test_a_row_missing_some_seeds_files_is_named(tmp_path):
    from aril_ros.policy import save_policy
    from tests.conftest import random_policy

    save_policy(random_policy("Swimmer-v5", seed=1), tmp_path / "mine-Swimmer-v5-seed1.pt")
    cfg = TimingTableConfig(envs="Swimmer-v5", defenses=f"mine={tmp_path}/mine-{{env}}-seed{{seed}}.pt",
                            training_seeds="1,2", learned="", out=str(tmp_path / "timing"))
    with pytest.raises(ValueError, match=r"mine on Swimmer-v5: no policy file .*mine-Swimmer-v5-seed2.pt"):
        timing_table(cfg)


def _row(clean: float, worst: dict[str, tuple[float, float]], learned: dict | None = None) -> dict:
    """A table row: clean's mean, and per budget the worst chooser's (mean, interval) (``learned``: every chooser's
    mean at that budget)."""
    cell = lambda mean, half=0.0: {"mean": mean, "ci95": half}  # noqa: E731
    budgets = {name: {"choosers": {"fixed": cell(*value)}, "worst": "fixed"} for name, value in worst.items()}
    for name, means in (learned or {}).items():
        chooser = min(means, key=means.get)
        budgets[name] = {"choosers": {c: cell(m) for c, m in means.items()}, "worst": chooser}
    return {"clean": cell(clean), "budgets": budgets}


def test_what_a_timing_table_shows_is_computed_from_it():
    from aril_ros.timing_table import Budget, findings

    swept = [Budget("delay", 1), Budget("delay", 2), Budget("drop", 2)]
    rows = {"dagger": _row(5000, {"delay1": (2000, 100), "delay2": (800, 100)},
                           {"drop2": {"fixed": 3000, "random": 2500, "learned": 1000}}),
            "timed": _row(4000, {"delay1": (2900, 100), "delay2": (700, 200)},
                          {"drop2": {"fixed": 2000, "random": 3000, "learned": 2400}})}
    text = findings(rows, swept, [Budget("drop", 2)])
    assert text.startswith("Under its worst timing attack timed keeps the most return in 2 of 3 columns (its "
                           "interval over the seeds clear of the next defense's in 2), DAgger in 1. Clean, timed "
                           "keeps 4000 (DAgger: 5000).")
    # drop 0.2: learned is the worst against DAgger only; shares of clean 20% and 60%, random 50% and 75%, fixed 60%, 50%
    assert text.endswith("With observations dropped 0.2, the learned timing adversary is the worst chooser against 1 "
                         "of 2 defenses and leaves 40% of clean return on average, random latency of the same budget "
                         "62%, fixed (the most every step) 55%.")


def test_the_timing_tables_settings_are_checked():
    with pytest.raises(ValueError, match="unknown timing attacks \\['late'\\]"):
        timing_table(TimingTableConfig(kinds="late"))
    with pytest.raises(ValueError, match="learned:= names budgets the table does not sweep: \\['delay5'\\]"):
        timing_table(TimingTableConfig(learned="delay5"))
    with pytest.raises(ValueError, match="unknown defense 'nobody'"):
        timing_table(TimingTableConfig(envs="Swimmer-v5", defenses="nobody", learned=""))
