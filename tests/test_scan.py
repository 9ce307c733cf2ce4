"""aril scan-adversary: a grid of ARIL-A settings trained and evaluated as sweep tasks, ranked."""
import json

import pytest

from aril_ros.args import ArgumentError
from aril_ros.scan import ScanConfig, grid_points, scan_adversary

TINY = dict(env="Swimmer-v5", mode="sensory", steps=256, episodes=2, horizon=30, workers=1)
SMALL_UPDATES = "n_envs=4 rollout=64"


def test_the_grid_is_the_product_of_its_groups_and_bad_groups_are_named():
    points = grid_points("lr=0.001,0.0003 ent_coef=0,0.01 n_envs=4")
    assert points[0] == {"lr": "0.001", "ent_coef": "0", "n_envs": "4"} and len(points) == 4
    with pytest.raises(ArgumentError, match="<field>=<value>,<value> groups"):
        grid_points("lr")
    with pytest.raises(ArgumentError, match="cannot scan 'eps': the scan sets it"):
        grid_points("eps=0.1,0.2")
    with pytest.raises(ArgumentError, match="names 'learning_rate', not a field of train-adversary; scannable: .*lr"):
        grid_points("learning_rate=0.1")


def test_a_bad_value_is_refused_before_anything_trains(tmp_path):
    with pytest.raises(ArgumentError, match="hidden:= takes int, got 'wide'"):
        scan_adversary(ScanConfig(**TINY, grid="hidden=64,wide", out=str(tmp_path / "scan")), log=lambda *a, **k: None)
    assert not list((tmp_path / "scan").glob("*.pt"))


@pytest.mark.slow
def test_every_point_is_trained_attacks_the_same_episodes_and_is_ranked(tmp_path):
    lines = []
    cfg = ScanConfig(**TINY, grid=f"lr=0.001,0.0003 {SMALL_UPDATES}", out=str(tmp_path / "scan"))
    payload = scan_adversary(cfg, log=lambda line, **_: lines.append(line))
    points = payload["points"]
    assert sorted(p["file"] for p in points) == ["adversary-0.pt", "adversary-1.pt"]
    assert [p["mean"] for p in points] == sorted(p["mean"] for p in points)  # the strongest attack first
    assert all(len(p["returns"]) == 2 for p in points) and payload["episode_seeds"] == "5000..5001"
    saved = json.loads((tmp_path / "scan" / "scan.json").read_text())
    assert saved["points"] == points and saved["command"].startswith("aril scan-adversary env:=Swimmer-v5")
    page = (tmp_path / "scan" / "scan.md").read_text()
    assert "| rank | lr | n_envs | rollout | return under attack |" in page
    assert "[scan] 2 points, 2 to train" in lines[0]
    # the trained files are kept: the same scan again trains nothing and ranks the same
    rerun = []
    again = scan_adversary(cfg, log=lambda line, **_: rerun.append(line))
    assert "[scan] 2 points, 0 to train" in rerun[0]
    assert [p["returns"] for p in again["points"]] == [p["returns"] for p in points]
