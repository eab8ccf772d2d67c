"""`reward check` and `reward map`: planted failures are found with their params, sweeps give hand-computed
values of the example reward, and the map puts the best line where the reward peaks."""

from __future__ import annotations

import numpy as np
import pytest

from racerlab.analysis.reward_tools import check_reward, parse_heading, reward_map, sample_states
from racerlab.cli import main
from racerlab.reward import EXAMPLE_REWARD
from tests.conftest import aws_track_path

PLANTED = """\
def reward_function(params):
    prev, nxt = params["closest_waypoints"]
    if prev == 37 and params["is_left_of_center"] and params["speed"] > 3.0:
        raise KeyError("planted at waypoint 37")
    if params["is_offtrack"]:
        return float("inf")
    return 1.0 + params["speed"]
"""

CENTRE = """\
def reward_function(params):
    return 1.0 - params["distance_from_center"] / (0.5 * params["track_width"])
"""


@pytest.fixture
def track(aws_track):
    return aws_track("reInvent2019_track")


def test_check_finds_the_planted_exception_with_its_params(track, tmp_path):
    f = tmp_path / "planted.py"
    f.write_text(PLANTED)
    rep = check_reward(f, track, per_segment=60)
    assert not rep.ok
    planted = [p for p in rep.problems if "KeyError" in p.message]
    assert len(planted) == 1
    p = planted[0]
    assert p.message.startswith(f"{f}:4: reward_function raised KeyError")
    assert p.params["closest_waypoints"] == [37, 38] and p.params["is_left_of_center"] and p.params["speed"] > 3
    assert p.count >= 2
    inf = [p for p in rep.problems if "returned inf" in p.message]
    assert len(inf) == 1 and inf[0].message.startswith(f"{f}:6:") and inf[0].params["is_offtrack"]
    text = rep.format()
    assert "PROBLEMS" in text and "closest_waypoints=[37, 38]" in text


def test_sampled_states_cover_the_cases(track):
    st = sample_states(track, per_segment=40)
    f = st.frame
    assert len(f) == 40 * (track.num_waypoints - 1)
    assert f["is_offtrack"].mean() > 0.03 and (~f["all_wheels_on_track"] & ~f["is_offtrack"]).any()
    assert f["is_reversed"].any() and f["lap_complete"].any() and (f["heading_error"] > 90).any()
    prev = np.asarray(st.params.cols["prev_waypoint"])
    assert set(prev.tolist()) == set(range(track.num_waypoints - 1))  # every segment visited


def test_example_reward_sweeps_by_hand(track):
    # example reward: 0.001 + centre * heading * (0.25 + 4 (speed / 4)^2); on the centre line, heading along: 1 * 1
    rep = check_reward(EXAMPLE_REWARD, track, per_segment=10)
    assert rep.ok
    speed = rep.sweeps["speed (m/s)"]["mean"]
    assert speed[2.0] == pytest.approx(0.001 + 0.25 + 1.0, abs=1e-9)
    assert speed[4.0] == pytest.approx(0.001 + 0.25 + 4.0, abs=1e-9)
    lateral = rep.sweeps["distance from centre (fraction of half width, + = left)"]["mean"]
    assert lateral[0.5] == pytest.approx(0.001 + (1 - 0.25) * 1.25, abs=1e-3)  # centre term 1 - (d / half)^2
    assert lateral[1.2] == pytest.approx(0.001)  # off the road: the floor
    heading = rep.sweeps["heading error (°, + = pointing left of the track)"]["mean"]
    assert heading[20] == pytest.approx(0.001 + (1 - 20 / 45) * 1.25, abs=1e-3)
    assert rep.rewards.min() >= 0.001 and "share of states per reward band" in rep.format()


def test_check_cli_exit_status(tmp_path, capsys):
    track = str(aws_track_path("reInvent2019_track"))
    f = tmp_path / "planted.py"
    f.write_text(PLANTED)
    assert main(["reward", "check", str(f), "--track", track, "--samples", "60"]) == 1
    assert "KeyError" in capsys.readouterr().out
    assert main(["reward", "check", str(EXAMPLE_REWARD), "--track", track, "--samples", "5"]) == 0
    bad = tmp_path / "syntax.py"
    bad.write_text("def reward_function(params)\n    return 1\n")
    assert main(["reward", "check", str(bad), "--track", track]) == 2
    assert "syntax error" in capsys.readouterr().err


def test_map_peaks_on_the_centre_line(track, tmp_path):
    f = tmp_path / "centre.py"
    f.write_text(CENTRE)
    rm = reward_map(f, track, speed=1.0, ds=0.1, across=21)
    n_margin = int(np.ceil(0.15 * 21))
    assert rm.reward.shape == (int(np.ceil(track.length / 0.1)), 21 + 2 * n_margin) and rm.failed == 0
    bx, by = rm.best_line()
    d = track.project(np.stack([bx, by], 1)).lateral
    assert np.abs(d).max() < 0.6 * track.width / 21  # the middle cell of 21 across
    assert np.nanmax(rm.reward) == pytest.approx(1.0, abs=0.05)


def test_map_cli_writes_a_png(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "map.png"
    rc = main(["reward", "map", str(EXAMPLE_REWARD), "--track", str(aws_track_path("reInvent2019_track")),
               "--speed", "3", "--heading", "aim:2", "--out", "map.png"])
    assert rc == 0 and capsys.readouterr().out.strip() == f"picture: {out}"  # where it is, not just its name
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 20_000


def test_heading_rules():
    assert parse_heading("along") == ("along", 0.0) and parse_heading("-15") == ("offset", -15.0)
    assert parse_heading("aim:3") == ("aim", 3.0)
    with pytest.raises(ValueError, match="along, against"):
        parse_heading("sideways")


def test_check_takes_the_track_of_the_model_folder_the_reward_is_in(tmp_path, capsys):
    from racerlab.model import init_model

    folder = init_model(tmp_path / "m", track="lab_oval")
    assert main(["reward", "check", str(folder.reward_path), "--samples", "5"]) == 0
    assert capsys.readouterr().out.startswith("reward check on lab_oval ")
    folder.config_path.write_text('[track]\nnames = ["no_such_track_anywhere"]\n')  # gone: the default track
    assert main(["reward", "check", str(folder.reward_path), "--samples", "5"]) == 0
    assert capsys.readouterr().out.startswith("reward check on lab_technical ")
    loose = tmp_path / "loose.py"  # not in a model folder: the default track
    loose.write_text(folder.reward_path.read_text())
    assert main(["reward", "check", str(loose), "--samples", "5"]) == 0
    assert capsys.readouterr().out.startswith("reward check on lab_technical ")
