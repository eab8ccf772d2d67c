"""`racerlab line` in-process: the files it writes, what is in them, and one-line errors."""

from __future__ import annotations

import csv
import json
import runpy

import numpy as np
import pytest

from racerlab.cli import main
from racerlab.line import racing_line, theoretical_limit
from racerlab.line.export import action_space, grip_speed
from racerlab.model import parse_model_metadata
from racerlab.spec import MAX_SPEED, MIN_SPEED
from tests.conftest import aws_track_path


def test_cli_prints_the_lap_and_writes_every_file(tmp_path, capsys):
    track = aws_track_path("reInvent2019_track")
    out = tmp_path / "line"
    assert main(["line", str(track), "--margin", "0.1", "--method", "mincurv", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    line, limit = racing_line(str(track)), theoretical_limit(str(track))
    assert f"line:  lap {line.lap_time:.3f} s" in text and "the whole car 0.1 m inside" in text
    assert f"limit: lap {limit.lap_time:.3f} s" in text and "0.115 m outside a border" in text
    stem = out / "reInvent2019_track_mincurv"
    assert f"wrote into {out}:" in text and f"py              {stem}.py" in text
    png = stem.with_suffix(".png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 20_000
    xy = np.load(stem.with_suffix(".npy"))
    assert xy.shape == line.xy.shape and np.allclose(xy, line.xy)
    rows = list(csv.DictReader(stem.with_suffix(".csv").open()))
    assert len(rows) == len(xy) and float(rows[-1]["time_s"]) < line.flying_lap_time
    assert float(rows[0]["s_m"]) == 0.0 and max(float(r["speed_mps"]) for r in rows) <= 4.0
    pasted = runpy.run_path(str(stem.with_suffix(".py")))
    assert np.allclose(np.array(pasted["racing_line"]), np.column_stack([line.xy, line.speed]), atol=1e-3)
    assert pasted["LAP_TIME"] == pytest.approx(line.lap_time, abs=1e-3)
    meta = parse_model_metadata(json.loads((out / "model_metadata.json").read_text()))
    assert meta.action_space_type == "discrete" and meta.actions.n == 15


def test_shortest_method_and_default_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["line", str(aws_track_path("reinvent_base")), "--method", "shortest", "--actions", "7"]) == 0
    folder = tmp_path / "reinvent_base_shortest_line"
    assert (folder / "reinvent_base_shortest.png").is_file()
    assert len(json.loads((folder / "model_metadata.json").read_text())["action_space"]) <= 7


@pytest.mark.parametrize("argv, words", [
    (["--margin", "0.3"], "too narrow"),
    (["--margin", "-0.3"], "--margin must be >= -0.231 m"),
    (["--actions", "2"], "--actions must be at least 3"),
    (["--method", "fastest"], "--method 'fastest' is not a line method; use one of mincurv, shortest"),
])
def test_user_mistakes_are_one_line(tmp_path, capsys, argv, words):
    track = str(aws_track_path("Virtual_May19_Train_track"))  # 0.60 m wide
    assert main(["line", track, "--out", str(tmp_path), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("racerlab: error:") and words in err and "\n" not in err


def test_open_track_is_refused_in_one_line(tmp_path, capsys):
    assert main(["line", str(aws_track_path("Straight_track")), "--out", str(tmp_path)]) == 2
    assert "closed loop" in capsys.readouterr().err


def test_action_space_covers_the_line_within_the_cars_limits(aws_track):
    line = racing_line(aws_track("2022_reinvent_champ"))
    acts = action_space(line, 12)
    steer, speed = np.array(acts.steering_deg), np.array(acts.speed)
    assert acts.n <= 12 and len(set(zip(steer, speed, strict=True))) == acts.n
    assert np.all(np.abs(steer) <= 30.0) and np.all((speed >= MIN_SPEED) & (speed <= MAX_SPEED))
    assert np.all(speed <= grip_speed(steer, line) + 1e-9)  # no action slides the car
    assert {-30.0, 30.0} <= set(steer.tolist())  # recovery at full lock both ways
    # every point of the line has an action within 4° (a fifteenth of the ±30° range) of its steering: the car's
    # yaw gain of 0.63 spreads what the line asks over a wider range of angles than the kinematic bicycle did
    # (within 3° then), so the same 12 actions cover it a little more coarsely
    need = line.steering_deg
    assert np.max(np.min(np.abs(need[:, None] - steer[None, :]), axis=1)) < 4.0
    # the same line gives the same actions
    assert action_space(line, 12) == acts


def _own_tracks(tmp_path, monkeypatch) -> list[str]:
    """Every track racerlab ships and one it generates (`racerlab tracks generate`, into a fresh user folder)."""
    from racerlab.track import registry

    monkeypatch.setenv("RACERLAB_HOME", str(tmp_path / "home"))
    assert main(["tracks", "generate", "--seed", "3", "--width", "0.76"]) == 0
    bundled = sorted(p.stem for p in registry.BUNDLED_DIR.glob("*.npy"))
    assert {"lab_technical", "lab_oval", "lab_grand_prix"} <= set(bundled)
    return [*bundled, "generated_3"]


def test_line_prints_the_line_and_the_limit_on_every_track_racerlab_ships_or_generates(tmp_path, monkeypatch, capsys):
    # the limit (the base point up to 0.115 m outside the borders) failed on all of them: the grown borders of a
    # straight road meet end to end, and the zero-length joint between them read as a wall across the road
    for name in _own_tracks(tmp_path, monkeypatch):
        capsys.readouterr()
        assert main(["line", name, "--out", str(tmp_path / name)]) == 0, capsys.readouterr().err
        text = capsys.readouterr().out
        line_lap = float(text.split("line:  lap ")[1].split(" s")[0])
        limit_lap = float(text.split("limit: lap ")[1].split(" s")[0])
        assert 0 < limit_lap < line_lap < 30, (name, text)  # the limit is faster than the line the car keeps inside


def test_a_failed_solve_never_calls_a_wide_road_too_narrow():
    from racerlab.errors import TrackError
    from racerlab.line import solve as S
    from racerlab.track import load

    t = load("lab_oval")  # 1.07 m wide everywhere; a bogus wall of segments across the road at the start
    ref = S.G.resample_polyline(t.center[:-1], 60, True)
    segs = S.G.border_segments(t)
    wall = (np.vstack([segs[0], t.inner[:1]]), np.vstack([segs[1], t.outer[:1] - t.inner[:1]]))
    with pytest.raises(TrackError) as err:
        S._room(t, ref, S.G.left_normals(ref, True), wall, 0.2, (2.0, 0.0))
    msg = str(err.value)
    assert "1.07 m wide" in msg and "too narrow" not in msg and "borders fold or cross" in msg


def test_line_for_an_effort_control_car_writes_that_version_and_nan_margin_is_one_line(tmp_path, capsys):
    assert main(["line", "lab_oval", "--simulator", "console", "--version", "4", "--out", str(tmp_path)]) == 0
    assert "effort control" in capsys.readouterr().out
    assert json.loads((tmp_path / "model_metadata.json").read_text())["version"] == "4"
    for argv, words in ((["--margin", "nan"], "--margin nan: not a number"),
                        (["--version", "five"], "--version five: not a model_metadata version")):
        assert main(["line", "lab_oval", "--out", str(tmp_path / "x"), *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert words in err and "\n" not in err
    assert not (tmp_path / "x").exists()
