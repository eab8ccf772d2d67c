"""Logs in the formats AWS really writes, built row by row from the facts (facts §7, §8, §12):

- a DRfC continuous evaluation, 3 trials of 3 laps: `episode` counts the laps completed so far, laps 1 and 2
  of a trial end at progress 100 with `in_progress` and done False, only the third says `lap_complete`;
- a 2019 robomaker log: 15 fields, no status column, radians, a reset row with steps 0 at each episode's start
  (the 2019 environment's `reset()` logged one before any action), every lap ending at progress 100, done True;
- tracks shipped by AWS under several names with identical geometry.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd
import pytest

from racerlab.analysis.episodes import episode_summary
from racerlab.analysis.load import load
from racerlab.analysis.report import log_track, write_report
from racerlab.analysis.rescore import compare, rescore
from tests.conftest import AWS_TRACKS, aws_track_path
from tests.logs.samples import HEADER_17, log_text, write

DT = 1.0 / 15.0


def continuous_evaluation_rows(laps_rows: list[list[int]]) -> tuple[list[str], list[float]]:
    """17-field rows of continuous-evaluation trials; `laps_rows[t][k]` rows in lap k of trial t.

    Returns the CSV lines and every lap's time as AWS times it (sim time from the reset, or from the
    previous lap's completion, to the end of the lap's last step)."""
    lines, times = [], []
    laps_done = 0
    t0 = 100.0
    for trial in laps_rows:
        step, clock = 0, t0  # each trial is an episode from a reset; its first row is the prepare step
        for k, n in enumerate(trial):
            start = clock
            for j in range(n):
                step += 1
                clock += DT
                progress = 100.0 if j == n - 1 else round(100.0 * (j + 1) / n, 4)
                last_lap = k == len(trial) - 1
                status = "prepare" if step == 1 else ("lap_complete" if j == n - 1 and last_lap else "in_progress")
                done = j == n - 1 and last_lap
                angle = 2 * math.pi * progress / 100
                lines.append(f"{laps_done},{step},{2.5 * math.cos(angle):.4f},{2.5 * math.sin(angle):.4f},"
                             f"{math.degrees(angle) + 90:.4f},0.00,2.00,3,{0.0 if step == 1 else 1.0:.4f},{done},"
                             f"True,{progress:.4f},{int(progress) % 60},15.71,{clock:.3f},{status},0.00")
            times.append(round(clock - start, 3))
            laps_done += 1
        t0 = clock + 5.0
    return lines, times


def test_multi_lap_evaluation_counts_every_lap_as_aws_does(tmp_path):
    laps_rows = [[130, 121, 119], [126, 118, 140], [124, 117, 122]]
    lines, times = continuous_evaluation_rows(laps_rows)
    folder = tmp_path / "model"
    write(folder / "evaluation-20240101120000" / "evaluation-simtrace" / "0-iteration.csv",
          HEADER_17 + "\n" + "\n".join(lines) + "\n")
    df = load(folder, "evaluation", cache=False)
    eps = episode_summary(df)
    assert len(eps) == 9 and eps["complete"].all()  # 9 of 9, as EvalMetrics lists 9 "Lap complete" laps
    assert eps["outcome"].tolist() == ["lap_complete"] * 9
    assert eps["lap_time"].to_numpy() == pytest.approx([n * DT for trial in laps_rows for n in trial], abs=2e-3)
    assert eps["lap_time"].to_numpy() == pytest.approx(times, abs=2e-3)
    assert eps["lap_time"].min() == pytest.approx(117 * DT)  # the best lap is a middle lap of trial 3

    deepracer = pytest.importorskip("deepracer.logs", reason="deepracer-utils is a test dependency")
    agg = deepracer.AnalysisUtils.simulation_agg(df.copy(), "stream", "unique_episode", is_eval=True)
    assert int(agg["complete"].sum()) == 9  # deepracer-utils: progress == 100

    html = write_report(folder, tmp_path / "r.html", kind="evaluation").read_text()
    summary = re.search(r"<b>complete laps</b></td><td>([^<]*)<", html).group(1)
    best = re.search(r"<b>best lap</b></td><td>([^<]*)<", html).group(1)
    assert summary == "9 (100.0 %)" and best.startswith(f"{117 * DT:.3f} s")


def robomaker_2019_lines(track, episodes: int, lap_steps: int) -> tuple[list[str], list[np.ndarray]]:
    """15-field SIM_TRACE_LOG lines of a 2019 training: yaw and steer in radians, tstamp a wall clock, a
    reset row with steps 0 and action 0, then `lap_steps` steps along the centre line to progress 100."""
    lines, progress_of = [], []
    cl = track.center
    seg = np.hypot(*np.diff(cl, axis=0).T)
    s = np.concatenate([[0], np.cumsum(seg)])
    wall = 1556000000.0
    for e in range(episodes):
        prog = np.round(np.linspace(0.0, 100.0, lap_steps + 1), 4)
        progress_of.append(prog)
        for step, p in enumerate(prog):
            x, y = np.interp(p / 100 * s[-1], s, cl[:, 0]), np.interp(p / 100 * s[-1], s, cl[:, 1])
            k = min(int(np.searchsorted(s, p / 100 * s[-1], side="right")), len(cl) - 1)
            yaw = math.atan2(cl[k, 1] - cl[k - 1, 1], cl[k, 0] - cl[k - 1, 0])
            steer, speed, action = (0.0, 0.0, 0) if step == 0 else (0.2618, 2.0, 4)
            done = step == lap_steps
            wall += 0.0667
            lines.append(f"{e},{step},{x:.4f},{y:.4f},{yaw:.4f},{steer:.2f},{speed:.2f},{action},1.0000,{done},"
                         f"True,{p:.4f},{k},{track.length:.2f},{wall:.4f}")
    return lines, progress_of


def test_2019_robomaker_log_counts_laps_and_rescores(tmp_path, aws_track):
    track = aws_track("reinvent_base")
    lines, progress_of = robomaker_2019_lines(track, episodes=4, lap_steps=60)
    log = write(tmp_path / "logs" / "training" / "2019-robomaker.log", log_text(lines))
    df = load(log, cache=False)
    assert df.attrs["converted_to_degrees"] and df.attrs["derived_status_rows"] == len(lines)
    assert (df.loc[df["steps"] == 0, "episode_status"] == "prepare").all()
    eps = episode_summary(df)
    assert len(eps) == 4 and eps["complete"].all() and (eps["outcome"] == "lap_complete").all()

    def pace(params):  # a popular reward: progress per step (raises ZeroDivisionError on a steps-0 row)
        return params["progress"] / params["steps"]

    res = rescore(df, pace, track)
    assert res.ok and res.failed == 0
    cmp = compare(df, res.new_reward)
    # the reset row is not scored (its reward reached no agent); every other row pays progress / steps
    expected = [sum(p[k] / k for k in range(1, len(p))) for p in progress_of]
    assert cmp["new_reward"].to_numpy() == pytest.approx(expected, rel=1e-6)


@pytest.fixture
def aws_tracks_on_path(monkeypatch, tmp_path):
    aws_track_path("reinvent_base")  # skips without the real files
    monkeypatch.setenv("RACERLAB_HOME", str(tmp_path / "home"))
    monkeypatch.setenv("RACERLAB_TRACK_PATH", str(AWS_TRACKS))


def test_identical_track_files_are_one_track(aws_tracks_on_path):
    df = pd.DataFrame({"track_len": [17.71] * 3})
    trk, note = log_track("some.log", df)
    assert trk is not None and trk.name == "reinvent_base"
    assert "reinvent_carpet, reinvent_concrete, reinvent_wood are the same geometry" in note
    # RL Speedway and Forever Raceway share a centre line and its length but not their width or direction:
    # four different tracks, so the report still asks
    trk, note = log_track("some.log", pd.DataFrame({"track_len": [25.11] * 3}))
    assert trk is None and "several known tracks are 25.11 m long" in note and "--track" in note
