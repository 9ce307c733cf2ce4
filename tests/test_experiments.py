import json

import pytest

from aril_ros.experiments import (
    AttackTableConfig,
    CalibrationConfig,
    attack_table,
    calibrate_eps,
)
from aril_ros.policy import save_policy

QUIET = dict(log=lambda *a, **k: None)
ONE = dict(workers=1)  # in this process: the patched registry and the fixtures' files are this process's


@pytest.mark.slow
def test_calibration_and_attack_table_end_to_end(tmp_path, make_policy):
    victim = save_policy(make_policy("Swimmer-v5", seed=1), tmp_path / "victim.pt")
    expert = save_policy(make_policy("Swimmer-v5", seed=2), tmp_path / "expert.pt")
    calibration = calibrate_eps(CalibrationConfig(envs="Swimmer-v5", modes="sensory", policy=str(victim),
                                                  expert=str(expert), grid="0.01,0.5", episodes=2, horizon=60,
                                                  max_drop=10.0, out=str(tmp_path / "cal"), **ONE), **QUIET)
    row = calibration["rows"][0]
    assert row["chosen_eps"] == 0.5 and len(row["sweep"]) == 2  # the loose rule keeps the largest eps
    assert "| Swimmer-v5 | sensory |" in (tmp_path / "cal.md").read_text()
    table = attack_table(AttackTableConfig(envs="Swimmer-v5", mode="sensory", policy=str(victim),
                                           expert=str(expert), calibration=str(tmp_path / "cal.json"),
                                           episodes=2, horizon=60, adversary_steps=2000, k=3,
                                           adversary_dir=str(tmp_path), out=str(tmp_path / "attacks"), **ONE), **QUIET)
    cells = table["rows"][0]["cells"]
    assert list(cells) == ["none", "random", "fgsm", "fgsm_k", "spsa", "aril_a", "fd_fgsm", "transfer", "aril_a_search",
                           "aril_a_directed"]
    assert cells["spsa"]["queries_per_step"] == 1 + 3 * (2 * 8 + 1)  # k:=3 iterations of 8 directions
    assert cells["fd_fgsm"]["queries_per_step"] == 3 * (2 * 3 + 1) + 1  # k:=3 iterations, as FGSM^k, 3 entries
    assert cells["aril_a_search"]["queries_per_step"] == 1 + 16 + 1  # its input action, 16 draws, the likeliest
    assert cells["aril_a_directed"]["queries_per_step"] == 1 + 2 * 3  # its input action, 2 per zero-order entry
    assert all(c["episodes"] == 2 and c["seeds"] == "2000..2001" for c in cells.values())
    assert cells["fgsm"]["eps"] == 0.5 and cells["none"]["eps"] == 0.0
    saved = json.loads((tmp_path / "attacks.json").read_text())
    assert all(c["command"].startswith("aril attack-table mode:=sensory")
               for c in saved["rows"][0]["cells"].values())
    assert cells["aril_a"]["adversary"]["steps"] >= 2000
    assert cells["aril_a_directed"]["adversary"]["settings"]["policy"] == "directed"
    assert (tmp_path / "directed-adversary-Swimmer-v5-sensory-victim.pt").exists()
    markdown = (tmp_path / "attacks.md").read_text()
    assert "| ARIL-A + search |" in markdown and "| 18 |" in markdown and "| ARIL-A, directed |" in markdown
    assert (tmp_path / "adversary-Swimmer-v5-sensory-victim.pt").exists()
    # transfer: FGSM^k on a surrogate fitted to the victim's answers at the table's eps, which asks the victim nothing
    surrogate = tmp_path / "surrogate-Swimmer-v5-sensory-victim.pt"
    made = cells["transfer"]["surrogate"]
    assert made["file"] == str(surrogate) and (made["victim"], made["eps"], made["horizon"]) == (str(victim), 0.5, 60)
    assert made["queries"] > 0 and 0.0 < made["fidelity"]["r2"] <= 1.0
    assert "queries_per_step" not in cells["transfer"] and "| FGSM^k on a surrogate |" in markdown
    fitted = surrogate.stat().st_mtime_ns
    attack_table(AttackTableConfig(envs="Swimmer-v5", mode="sensory", policy=str(victim), expert=str(expert),
                                   calibration=str(tmp_path / "cal.json"), episodes=2, horizon=60, adversary_steps=2000,
                                   k=3, search=0, adversary_dir=str(tmp_path), out=str(tmp_path / "again"), **ONE),
                 **QUIET)
    assert surrogate.stat().st_mtime_ns == fitted  # the same victim, eps and horizon: reused
    # rows:= runs the rows it names again and keeps the others, which must share the settings that shape them
    table_args = dict(envs="Swimmer-v5", mode="sensory", policy=str(victim), expert=str(expert),
                      calibration=str(tmp_path / "cal.json"), episodes=2, horizon=60, adversary_dir=str(tmp_path),
                      out=str(tmp_path / "attacks"), **ONE)
    rerun = attack_table(AttackTableConfig(k=3, rows="fd_fgsm", **table_args), **QUIET)["rows"][0]["cells"]
    assert list(rerun) == list(cells)
    assert all(rerun[row] == saved["rows"][0]["cells"][row] for row in cells if row != "fd_fgsm")
    assert rerun["fd_fgsm"]["mean"] == cells["fd_fgsm"]["mean"] and "rows:=fd_fgsm" in rerun["fd_fgsm"]["command"]
    with pytest.raises(ValueError, match=r"Swimmer-v5 \w+ row was run with k:=3 .this run: k:=2"):
        attack_table(AttackTableConfig(k=2, rows="fd_fgsm", **table_args), **QUIET)
    elsewhere = json.loads((tmp_path / "attacks.json").read_text())
    elsewhere["rows"][0]["cells"]["random"]["versions"]["cpu"] = "Another CPU (AVX2)"
    (tmp_path / "attacks.json").write_text(json.dumps(elsewhere))
    with pytest.raises(ValueError, match=r"Swimmer-v5 random row was run on Another CPU \(AVX2\) .this machine: "):
        attack_table(AttackTableConfig(k=3, rows="fd_fgsm", **table_args), **QUIET)
    some = attack_table(AttackTableConfig(k=3, rows="none,fd_fgsm", **{**table_args, "out": str(tmp_path / "some")}),
                        **QUIET)  # a table of some rows alone, to a new file
    assert list(some["rows"][0]["cells"]) == ["none", "fd_fgsm"]
    assert "| Swimmer-v5 (eps 0.5) |" in (tmp_path / "some.md").read_text()
    with pytest.raises(ValueError, match="no clean row of Swimmer-v5"):
        attack_table(AttackTableConfig(k=3, rows="fd_fgsm", **{**table_args, "out": str(tmp_path / "new")}), **QUIET)
    with pytest.raises(ValueError, match="row"):
        attack_table(AttackTableConfig(rows="fgsm_kk", **table_args), **QUIET)


@pytest.mark.slow
def test_calibration_fills_in_mode_by_mode(tmp_path, make_policy):
    victim = save_policy(make_policy("Swimmer-v5", seed=1), tmp_path / "victim.pt")
    common = dict(envs="Swimmer-v5", policy=str(victim), expert=str(victim), grid="0.01", episodes=1, horizon=20,
                  out=str(tmp_path / "cal"), **ONE)
    calibrate_eps(CalibrationConfig(modes="sensory", **common), **QUIET)
    payload = calibrate_eps(CalibrationConfig(modes="physical", **common), **QUIET)
    assert [(r["env"], r["mode"]) for r in payload["rows"]] == [("Swimmer-v5", "physical"), ("Swimmer-v5", "sensory")]
    assert "modes:=sensory" in payload["rows"][1]["command"]
    # another victim for an env starts that env anew instead of mixing two victims' rows in one env
    other = save_policy(make_policy("Swimmer-v5", seed=3), tmp_path / "other.pt")
    payload = calibrate_eps(CalibrationConfig(modes="sensory", **{**common, "policy": str(other)}), **QUIET)
    assert [(r["env"], r["mode"], r["victim"]) for r in payload["rows"]] == [("Swimmer-v5", "sensory", str(other))]
    # another env, calibrated against a learner of its own, joins the file beside it (a user's onboarded envs)
    hopper = save_policy(make_policy("Hopper-v5", seed=4), tmp_path / "hopper.pt")
    payload = calibrate_eps(CalibrationConfig(modes="sensory", **{**common, "envs": "Hopper-v5", "policy": str(hopper),
                                                                  "expert": str(hopper)}), **QUIET)
    assert [(r["env"], r["victim"]) for r in payload["rows"]] == [("Swimmer-v5", str(other)), ("Hopper-v5", str(hopper))]
    assert payload["victim"] == "per row" and f"| Hopper-v5 | sensory | {hopper} |" in (tmp_path / "cal.md").read_text()


@pytest.mark.slow
def test_defense_table_reports_each_defense_under_its_strongest_attack(tmp_path, make_policy, monkeypatch):
    from aril_ros import registry
    from aril_ros.adversary import load_adversary
    from aril_ros.experiments import DefenseTableConfig, defense_table
    from aril_ros.sweep import digest_of

    monkeypatch.setattr(registry, "DATA_DIR", tmp_path / "data")  # bundled policies of its own, no adversary to reuse
    for seed, (kind, name) in enumerate((("expert", "Swimmer-v5"), ("dagger", "Swimmer-v5"),
                                         ("aril", "Swimmer-v5-sensory"))):
        save_policy(make_policy("Swimmer-v5", seed=seed), tmp_path / "data" / kind / f"{name}.pt")
    (tmp_path / "cal.json").write_text(json.dumps({"rows": [{"env": "Swimmer-v5", "mode": "sensory",
                                                             "chosen_eps": 0.3}]}))
    payload = defense_table(DefenseTableConfig(envs="Swimmer-v5", defenses="dagger,aril", calibration=str(tmp_path / "cal.json"),
                                               episodes=2, horizon=60, adversary_steps=2000, k=3,
                                               adversary_dir=str(tmp_path / "adv"), out=str(tmp_path / "def"), **ONE), **QUIET)
    row = payload["rows"][0]
    for defense in ("dagger", "aril"):
        cell = row["cells"][defense]
        worst = min(cell["attacks"].values(), key=lambda a: a["mean"])
        assert cell["mean"] == worst["mean"] and cell["attacks"][cell["worst"]] == worst
        assert cell["drop"] == round(1 - cell["mean"] / row["dagger_clean"], 4)
        # trained against the defense by its bundled name (any node finds its own copy), that very file
        bundled = tmp_path / "data" / defense / f"Swimmer-v5{'-sensory' if defense == 'aril' else ''}.pt"
        assert cell["adversary"]["victim"] == defense
        assert cell["adversary"]["victim_sha256"] == digest_of(bundled.read_bytes())
        assert (tmp_path / "adv" / f"Swimmer-v5-sensory-{defense}.pt").exists()
    assert row["dagger_clean"] == row["cells"]["dagger"]["clean"]
    text = (tmp_path / "def.md").read_text()
    assert "| DAgger, clean |" in text and "| ARIL |" in text

    # a later run of one defense keeps the others' cells; with two adversary seeds its ARIL-A is the stronger one
    payload = defense_table(DefenseTableConfig(envs="Swimmer-v5", defenses="aril", calibration=str(tmp_path / "cal.json"),
                                               episodes=2, horizon=60, adversary_steps=2000, adversary_seeds=2, k=3,
                                               adversary_dir=str(tmp_path / "adv"), out=str(tmp_path / "def"), **ONE), **QUIET)
    assert set(payload["rows"][0]["cells"]) == {"dagger", "aril"}
    assert payload["rows"][0]["cells"]["dagger"] == row["cells"]["dagger"]
    aril = payload["rows"][0]["cells"]["aril"]
    assert aril["aril_a_seeds"][0] == row["cells"]["aril"]["attacks"]["aril_a"]["mean"]  # seed 0's file was reused
    assert aril["attacks"]["aril_a"]["mean"] == min(aril["aril_a_seeds"])
    assert load_adversary(tmp_path / "adv" / "Swimmer-v5-sensory-aril-seed1.pt").meta["provenance"]["seed"] == 1
    assert aril["adversary"]["seed"] == aril["aril_a_seeds"].index(min(aril["aril_a_seeds"]))
    assert "the strongest of 1 or 2" in (tmp_path / "def.md").read_text()  # dagger's cell kept its one


@pytest.mark.slow
def test_a_victim_too_fragile_for_the_grid_is_calibrated_below_it(tmp_path, make_policy):
    """Where even the grid's smallest eps breaks the rule (an onboarded Hopper under physical attack), halvings of it
    are tried, and the chosen eps is the largest that keeps the rule, or the smallest tried, said so."""
    from aril_ros.experiments import FINER

    victim = save_policy(make_policy("Swimmer-v5", seed=1), tmp_path / "victim.pt")
    expert = save_policy(make_policy("Swimmer-v5", seed=2), tmp_path / "expert.pt")
    common = dict(envs="Swimmer-v5", modes="sensory", policy=str(victim), expert=str(expert), episodes=2, horizon=60,
                  **ONE)
    loose = calibrate_eps(CalibrationConfig(grid="0.5", max_drop=10.0, out=str(tmp_path / "loose"), **common), **QUIET)
    assert [s["eps"] for s in loose["rows"][0]["sweep"]] == [0.5]  # the grid kept the rule: nothing more tried
    sweep = calibrate_eps(CalibrationConfig(grid="0.5", max_drop=-10.0, out=str(tmp_path / "strict"), **common),
                          **QUIET)["rows"][0]
    assert [s["eps"] for s in sweep["sweep"]] == [0.5 / 2 ** k for k in range(FINER, -1, -1)]
    assert sweep["chosen_eps"] == 0.5 / 2 ** FINER  # no eps can keep a rule of a negative drop
    assert "(even the smallest eps broke the rule: the smallest tried)" in (tmp_path / "strict.md").read_text()
