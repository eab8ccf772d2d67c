"""Generalisation: held-out AWS tracks, the share lapped, and the drop under randomisation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from racerlab.cli import main
from racerlab.errors import RacerlabError
from racerlab.evaluate import generalise
from racerlab.evaluate.generalise import evaluate_tracks, held_out_tracks
from racerlab.sim.pursuit import PurePursuit
from tests.conftest import aws_track_path
from tests.evaluate.models import write_checkpoint, write_model

CONTINUOUS = {"steering_angle": {"low": -30.0, "high": 30.0}, "speed": {"low": 0.5, "high": 2.0}}
NAMES = ["reInvent2019_track", "reInvent2019_track_ccw", "reInvent2019_track_cw", "Monaco", "Monaco_building",
         "Straight_track", "Oval_track", "China_track"]


@pytest.fixture
def track_dir(tmp_path):
    folder = tmp_path / "tracks"
    folder.mkdir()
    for name in NAMES:
        (folder / f"{name}.npy").symlink_to(aws_track_path(name))
    return folder


def test_held_out_tracks_leave_out_training_layouts_copies_and_open_tracks(track_dir):
    picked = held_out_tracks(track_dir, 3, exclude=["/x/reInvent2019_track.npy"])
    stems = sorted(p.stem for p in picked)
    # reInvent2019 (and its _cw/_ccw variants) trained on; Straight_track is open; Monaco_building is Monaco
    assert len(stems) == 3 and "Oval_track" in stems and "China_track" in stems
    assert len({"Monaco", "Monaco_building"} & set(stems)) == 1
    assert picked == held_out_tracks(track_dir, 3, exclude=["reInvent2019_track"])  # seeded
    with pytest.raises(RacerlabError, match="3 closed track layouts not excluded, fewer than the 4 asked"):
        held_out_tracks(track_dir, 4, exclude=["reInvent2019_track"])
    assert len(held_out_tracks(track_dir, 4)) == 4  # the reInvent2019 layout counts once


def _pursuit_unless_delayed(model, world, device="cpu"):
    """A centre-line pure pursuit at 1 m/s; under a randomisation with latency it steers straight ahead."""
    ctl = PurePursuit.on_centre_line(world.sim.track, speed=1.0)
    blind = world.randomise is not None and world.randomise.latency_steps > 0

    def policy(obs):
        steer, speed = ctl(world.sim)
        a = 0.0 if blind else float(np.clip(steer[0] / 30.0, -1, 1))
        return np.array([[a, (speed[0] - 0.5) / 1.5 * 2 - 1]])

    return policy


def test_share_of_tracks_lapped_and_the_drop_under_randomisation(tmp_path, monkeypatch):
    folder = write_model(tmp_path / "m", aws_track_path("reInvent2019_track"), CONTINUOUS)
    write_checkpoint(folder)
    monkeypatch.setattr(generalise, "make_policy", _pursuit_unless_delayed)
    tracks = [aws_track_path("Oval_track"), aws_track_path("reInvent2019_wide")]
    res = evaluate_tracks(folder.path, tracks, trials=2, randomise={"latency_steps": 1})
    assert [o.laps for o in res.tracks] == [2, 2] and res.share == 1.0
    assert 18 < res.tracks[0].best_lap_time < 30  # Oval_track is 20 m long, driven at 1 m/s
    assert [o.laps for o in res.randomised] == [0, 0] and res.randomised_share == 0.0 and res.drop == 1.0
    assert all(o.best_progress < 100 for o in res.randomised)
    out = res.to_json()
    assert out["share_completed"] == 1.0 and out["drop_under_randomisation"] == 1.0
    assert "a drop of 100%" in res.report()
    # the picture: one panel per track, the path of the lap drawn (a lap of Oval_track ends where it started)
    oval = res.tracks[0].path
    assert len(oval) == round(res.tracks[0].best_lap_time * 15) and np.hypot(*(oval[-1] - oval[0])) < 0.2
    picture = generalise.save_picture(res, tmp_path / "pic" / "tracks.png", randomised=True)
    assert picture.stat().st_size > 10_000


def test_cli_generalisation_writes_json_and_refuses_an_empty_randomise_table(tmp_path, track_dir, capsys):
    folder = write_model(tmp_path / "m", aws_track_path("reInvent2019_track"), CONTINUOUS)
    write_checkpoint(folder)
    out = tmp_path / "gen.json"
    assert main(["evaluate", str(folder.path), "--tracks-from", str(track_dir), "--count", "2", "--trials", "1",
                 "--json", str(out), "--no-limits"]) == 0
    data = json.loads(out.read_text())
    assert data["tracks"] == 2 and 0.0 <= data["share_completed"] <= 1.0 and data["randomised_share_completed"] is None
    assert all(row["limit"] is None for row in data["per_track"])
    assert "laps completed on" in capsys.readouterr().out
    assert (folder.path / "generalisation" / "tracks.png").is_file()
    assert main(["evaluate", str(folder.path), "--tracks-from", str(track_dir), "--randomise"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "[randomise] sets no option" in err[0]


@pytest.mark.parametrize(("flags", "throttle"), [([], 2.0), (["--speed-scale", "0.5"], 1.0),
                                                  (["--speed-scale", "0.5", "--top-speed", "3"], 1.5)])
def test_evaluation_takes_speeds_relative_to_the_action_space_top(tmp_path, flags, throttle):
    import pandas as pd

    folder = write_model(tmp_path / "m", aws_track_path("reInvent2019_track"), ((0.0, 2.0),))
    write_checkpoint(folder)
    assert main(["evaluate", str(folder.path), "--trials", "1", "--max-resets", "0", *flags]) == 0
    trace = pd.read_csv(next(folder.path.glob("evaluation-*/evaluation-simtrace/0-iteration.csv")))
    # the log keeps the model's action (2 m/s, as AWS logs it); the car drives at the mapped speed
    assert trace["throttle"].iloc[1:].max() == pytest.approx(2.0)
    driven = np.hypot(np.diff(trace["X"]), np.diff(trace["Y"])) * 15  # m/s between rows, 15 steps a second
    assert throttle * 0.9 < driven.max() <= throttle * 1.02


def test_race_under_the_models_randomise_table_says_so(tmp_path, capsys):
    folder = write_model(tmp_path / "m", aws_track_path("reInvent2019_track"), ((0.0, 1.0),))
    write_checkpoint(folder)
    folder.config_path.write_text(folder.config_path.read_text() + "[randomise]\nlatency_steps = 1\n")
    assert main(["evaluate", str(folder.path), "--trials", "1", "--max-resets", "0", "--randomise"]) == 0
    assert "randomised (latency_steps 1)" in capsys.readouterr().out
    summary = json.loads(next(folder.path.glob("evaluation-*/summary.json")).read_text())
    assert summary["randomise"] == {"latency_steps": 1}


def test_each_track_reports_its_mean_lap_over_its_limit():
    a = generalise.TrackOutcome("a", 2, 3, 100.0, 6.0, [6.0, 6.6], limit=5.0)
    b = generalise.TrackOutcome("b", 0, 3, 54.0, None, [], limit=7.0)
    assert a.mean_lap_time == pytest.approx(6.3) and a.ratio == pytest.approx(1.26) and b.ratio is None
    res = generalise.TracksResult("m", "best", [a, b])
    assert res.mean_ratio(res.tracks) == pytest.approx(1.26)  # over the tracks lapped
    text = res.report()
    assert "mean lap 1.260x the limit" in text and "1.260x" in text.splitlines()[2] and "54 %" in text
    assert res.to_json()["per_track"][0]["ratio_to_limit"] == 1.26


def test_a_limit_is_the_models_cars_within_its_actions_and_solved_once(tmp_path, monkeypatch, aws_track):
    from racerlab import line
    from racerlab.model.metadata import ContinuousActions
    from racerlab.spec import car_params

    monkeypatch.setenv("RACERLAB_CACHE_DIR", str(tmp_path))
    oval = aws_track("Oval_track")
    car = car_params("droa", "5")
    fast = generalise.model_limit(car, ContinuousActions(-30, 30, 1.0, 4.0))(oval)
    slow = generalise.model_limit(car, ContinuousActions(-30, 30, 0.5, 2.0))(oval)
    assert fast == pytest.approx(line.theoretical_limit(oval, car=car).lap_time)
    # a lap goes round the oval's convex inner border (17.63 m) no more than 0.231 m inside it (the off-track
    # rule): at least 17.63 - 2 pi 0.231 = 16.1 m, at 2 m/s x 1.0135 (the wheels' ground factor) 7.9 s or more
    assert slow > fast and slow >= 16.1 / (2.0 * 1.0135)
    monkeypatch.setattr(line, "theoretical_limit", lambda *a, **k: pytest.fail("solved again"))
    assert generalise.model_limit(car, ContinuousActions(-30, 30, 1.0, 4.0))(oval) == fast  # from the cache
