"""Every step-log variant, written by hand from the format facts, loads with the right rows and units."""

from __future__ import annotations

import math

import numpy as np
import pytest

from racerlab.analysis import load
from racerlab.logs import LogFileError
from racerlab.logs.read import read_sim_trace_log, read_simtrace_csv

from .samples import HEADER_17, csv_text, log_text, radian_rows, rows, tar_gz, write


@pytest.fixture
def cache(tmp_path):
    return tmp_path / "cache"


@pytest.mark.parametrize("fields", [15, 16, 17, 18, 19])
def test_sim_trace_log_field_counts(tmp_path, cache, fields):
    lines = rows(fields, 0) + rows(fields, 1)
    path = write(tmp_path / "logs" / "training" / "job-robomaker.log", log_text(lines))
    df = load(path, cache_dir=cache)
    assert len(df) == 6
    assert df["yaw"].iloc[0] == pytest.approx(-132.2484)  # degrees stay degrees
    assert df["steering_angle"].tolist()[:3] == [-30.0, 15.0, 0.0]
    assert df["x"].iloc[1] == pytest.approx(3.0698) and df["track_len"].iloc[0] == 23.12
    assert df["done"].tolist() == [False, False, True] * 2
    assert df["on_track"].tolist()[:3] == [True, True, False]
    assert df["action"].tolist() == [3] * 6
    if fields >= 16:
        assert df["episode_status"].tolist()[:3] == ["prepare", "in_progress", "off_track"]
        assert df.attrs["derived_status_rows"] == 0
    else:  # no status column: filled as the 2019 environment ended episodes (done off the road, done on it)
        assert df["episode_status"].tolist() == ["in_progress", "in_progress", "off_track",
                                                 "in_progress", "in_progress", "immobilized"]
        assert df.attrs["derived_status_rows"] == 6
    assert np.isnan(df["pause_duration"]).all() == (fields < 17)
    if fields == 19:
        assert df["wall_clock"].iloc[0] == pytest.approx(1700000000.1)
        assert (df["obstacle_crash_counter"] == 0).all()
    elif fields == 18:  # simapp 5.3.3: the 18th field is the obstacle crash counter
        assert (df["obstacle_crash_counter"] == 0).all() and df["wall_clock"].isna().all()


def test_eighteen_fields_with_a_wall_clock_in_the_last_place(tmp_path, cache):
    lines = [",".join(r.split(",")[:17] + [r.split(",")[18]]) for r in rows(19, 0)]
    df = load(write(tmp_path / "x.log", log_text(lines)), cache_dir=cache)
    assert df["wall_clock"].iloc[0] == pytest.approx(1700000000.1)
    assert df["obstacle_crash_counter"].isna().all()


def test_node_prefixes_and_hyperparameters_from_the_header(tmp_path, cache):
    lines = [r for e in range(6) for r in rows(19, e)]
    text = log_text(lines, prefix="[rl_coach-1] [rollout_worker] ", hyper={"num_episodes_between_training": 2,
                                                                            "lr": 0.0003})
    df = load(write(tmp_path / "logs" / "training" / "a-simulation.log", text), cache_dir=cache)
    assert len(df) == 18
    assert df.groupby("episode")["iteration"].first().tolist() == [0, 0, 1, 1, 2, 2]
    assert df["unique_episode"].tolist() == [e for e in range(6) for _ in range(3)]


def test_several_training_logs_are_workers_sharing_each_iteration(tmp_path, cache):
    hyper = {"num_episodes_between_training": 4}
    for w in range(2):
        write(tmp_path / "logs" / f"robomaker-{w + 1}.log", log_text([r for e in range(4) for r in rows(19, e)],
                                                                     hyper=hyper))
    df = load(tmp_path / "logs", cache_dir=cache)
    firsts = df.groupby("unique_episode")[["iteration", "worker", "episode"]].first()
    assert firsts["iteration"].tolist() == [0, 0, 0, 0, 1, 1, 1, 1]  # 2 episodes per worker per iteration
    assert firsts["worker"].tolist() == [0, 0, 1, 1, 0, 0, 1, 1]
    assert firsts["episode"].tolist() == [0, 1, 0, 1, 2, 3, 2, 3]


def test_rolled_log_parts_are_read_oldest_first(tmp_path, cache):
    folder = tmp_path / "logs"
    write(folder / "robomaker.log.2", log_text(rows(19, 0)))
    write(folder / "robomaker.log.1", log_text(rows(19, 1)))
    write(folder / "robomaker.log", log_text(rows(19, 2)))
    df = load(folder, cache_dir=cache)
    assert df["episode"].tolist() == [0, 0, 0, 1, 1, 1, 2, 2, 2]
    assert set(df["worker"]) == {0}


@pytest.mark.parametrize("action", ["[-12.5 1.25]", "[-12.5, 1.25]"])
def test_continuous_action_both_spellings(tmp_path, cache, action):
    df = load(write(tmp_path / "c.log", log_text(rows(19, 0, action))), cache_dir=cache)
    assert df["action"].tolist() == [-1, -1, -1]  # deepracer-utils' marker for a continuous action
    assert df["speed"].tolist() == [0.5, 1.5, 2.0]
    assert df["reward"].tolist() == [0.0, 1.25, 0.5]  # the fields after the action are not shifted


def test_continuous_action_in_a_csv(tmp_path, cache):
    path = write(tmp_path / "training-simtrace" / "0-iteration.csv", csv_text([0], action="[-12.5 1.25]"))
    df = load(path.parent.parent, cache_dir=cache)
    assert df["action"].tolist() == [-1, -1, -1] and df["steering_angle"].tolist() == [-30.0, 15.0, 0.0]


def test_radians_in_2019_logs_become_degrees(tmp_path, cache):
    path = write(tmp_path / "2019.log", log_text(radian_rows(0) + radian_rows(1)))
    df = load(path, cache_dir=cache)
    assert df["steering_angle"].iloc[0] == pytest.approx(-30.0, abs=1e-3)
    assert df["yaw"].iloc[0] == pytest.approx(math.degrees(-2.3082))
    assert df["tstamp"].iloc[0] == pytest.approx(1556000000.101)
    assert df.attrs["converted_to_degrees"] == [str(path)]
    again = load(path, cache_dir=cache)  # from the cache: still converted, still reported
    assert again["steering_angle"].iloc[0] == pytest.approx(-30.0, abs=1e-3)
    assert again.attrs["converted_to_degrees"] == [str(path)]


def test_degree_logs_are_left_alone(tmp_path, cache):
    df = load(write(tmp_path / "new.log", log_text(rows(17, 0))), cache_dir=cache)
    assert df.attrs["converted_to_degrees"] == [] and df["yaw"].iloc[0] == pytest.approx(-132.2484)


def test_seventeen_column_csv_and_gzip_csv(tmp_path, cache):
    folder = tmp_path / "model"
    write(folder / "training-simtrace" / "0-iteration.csv", csv_text([0, 1], HEADER_17, 17))
    write(folder / "training-simtrace" / "1-iteration.csv.gz", csv_text([2, 3], HEADER_17, 17))
    df = load(folder, cache_dir=cache)
    assert len(df) == 12 and df["iteration"].tolist() == [0] * 6 + [1] * 6
    assert df["wall_clock"].isna().all() and df["obstacle_crash_counter"].isna().all()
    assert (df["pause_duration"] == 0).all()


def test_mixed_headers_keep_file_order(tmp_path, cache):
    folder = tmp_path / "model" / "training-simtrace"
    write(folder / "0-iteration.csv", csv_text([0], HEADER_17, 17))
    write(folder / "1-iteration.csv", csv_text([1, 2]))
    write(folder / "2-iteration.csv", csv_text([3], HEADER_17, 17))
    write(folder / "3-iteration.csv", "\n".join(csv_text([4]).splitlines()[:2]) + "\n\n" + rows(19, 4)[1] + "\n")
    df = load(folder.parent, cache_dir=cache)
    assert df["episode"].tolist() == [0] * 3 + [1] * 3 + [2] * 3 + [3] * 3 + [4] * 2
    assert df["wall_clock"].isna().tolist() == [True] * 3 + [False] * 6 + [True] * 3 + [False] * 2


def test_old_console_tar_gz_read_in_place(tmp_path, cache):
    hyper = {"num_episodes_between_training": 2}
    members = {
        "sim-trace/training/training-simtrace/0-iteration.csv": csv_text([0, 1]),
        "sim-trace/training/training-simtrace/1-iteration.csv": csv_text([2, 3]),
        "logs/training/training-20240101120000-abc-robomaker.log": log_text(
            [r for e in range(4) for r in rows(19, e)], hyper=hyper),
        "sim-trace/evaluation/20240102120000-xyz/evaluation-simtrace/0-iteration.csv": csv_text([0, 1, 2]),
        "logs/evaluation/evaluation-20240102120000-xyz-robomaker.log": log_text(rows(19, 0)),
    }
    archive = tar_gz(tmp_path / "console-model.tar.gz", members)
    train = load(archive, cache_dir=cache)
    assert len(train) == 12 and train["iteration"].max() == 1  # the CSVs, not the log copy of the same steps
    ev = load(archive, "evaluation", cache_dir=cache)
    assert len(ev) == 9 and set(ev["stream"]) == {"20240102120000"}


def test_droa_layout_with_logs_only(tmp_path, cache):
    folder = tmp_path / "droa"
    write(folder / "logs" / "training" / "2025-01-01T00-00-00-simulation.log",
          log_text([r for e in range(3) for r in rows(19, e)], prefix="[rollout_node-1] "))
    df = load(folder, cache_dir=cache)
    assert len(df) == 9


def test_garbled_csv_names_file_and_line(tmp_path, cache):
    text = csv_text([0, 1]).splitlines()
    text[3] = text[3].replace("3.0798", "3.07x8")
    path = write(tmp_path / "m" / "training-simtrace" / "4-iteration.csv", "\n".join(text) + "\n")
    with pytest.raises(LogFileError, match=r"4-iteration\.csv:4: X is not a number \('3\.07x8'\)"):
        load(tmp_path / "m", cache_dir=cache)
    text[3] = "0,3,1.0"
    write(path, "\n".join(text) + "\n")
    with pytest.raises(LogFileError, match=r"4-iteration\.csv:4: expected 19 fields, got 3"):
        load(tmp_path / "m", cache_dir=cache)


def test_garbled_log_line_names_file_and_line(tmp_path, cache):
    lines = rows(19, 0)
    lines[1] = lines[1].replace("True", "Maybe", 1)
    path = write(tmp_path / "bad.log", log_text(lines))
    with pytest.raises(LogFileError, match=r"bad\.log:5: all_wheels_on_track is not True/False"):
        load(path, cache_dir=cache)
    write(path, log_text(["1,2,3"]))
    with pytest.raises(LogFileError, match=r"bad\.log:3: expected 15 to 19 fields, got 3"):
        load(path, cache_dir=cache)


def test_not_a_simtrace_header(tmp_path):
    with pytest.raises(LogFileError, match=r"a\.csv:1: not a simtrace CSV header"):
        read_simtrace_csv(b"foo,bar\n1,2\n", "a.csv")


def test_nothing_to_load_is_a_clear_error(tmp_path, cache):
    (tmp_path / "empty").mkdir()
    with pytest.raises(LogFileError, match="empty: found no step logs"):
        load(tmp_path / "empty", cache_dir=cache)


def test_log_without_trace_lines_gives_an_empty_table():
    table, info = read_sim_trace_log(b"hello\nworld\n", "x.log")
    assert table.num_rows == 0 and info["hyperparameters"] is None


def test_files_on_disk_equal_the_general_reader(tmp_path):
    from racerlab.logs.read import read_simtrace_csvs, read_simtrace_files

    texts = [csv_text([0, 1]), csv_text([2]).rstrip("\n"), csv_text([3, 4], HEADER_17, 17),
             csv_text([5], fields=19, action="[0.5 1.2]")]
    paths = [write(tmp_path / f"{i}-iteration.csv", t) for i, t in enumerate(texts)]
    # one header, discrete actions, one file without a final newline: rows per file, exact integer types
    table, counts = read_simtrace_files([str(p) for p in paths[:2]], [str(p) for p in paths[:2]])
    general, general_counts = read_simtrace_csvs([(str(p), p.read_bytes()) for p in paths[:2]])
    assert counts.tolist() == general_counts.tolist() == [6, 3] and table.equals(general)
    assert table.column("action").to_pylist() == [3] * 9 and table.column("episode").type == "int64"
    # two headers and a continuous action: each file its own layout, back in the order given
    mixed, mixed_counts = read_simtrace_files([str(p) for p in paths], [str(p) for p in paths])
    assert mixed_counts.tolist() == [6, 3, 6, 3] and mixed.column("action").to_pylist() == [3] * 15 + [-1] * 3
    assert mixed.column("episode").to_pylist() == [0] * 3 + [1] * 3 + [2] * 3 + [3] * 3 + [4] * 3 + [5] * 3
    assert np.isnan(mixed.column("wall_clock").to_numpy()[9:15]).all()