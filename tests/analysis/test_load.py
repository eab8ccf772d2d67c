"""racerlab.analysis.load on model folders: round trip from the writers, workers, evaluations, the cache,
and deepracer-utils reading the same folder."""

from __future__ import annotations

import logging
import os

import numpy as np
import pandas as pd
import pytest

from racerlab.analysis import FRAME_COLUMNS, load, load_metrics
from racerlab.logs import (
    EvalMetrics,
    LogFileError,
    SimtraceWriter,
    TrainingMetrics,
    eval_simtrace_path,
    evaluation_dir,
    training_metrics_path,
    training_simtrace_path,
)
from racerlab.logs.synthetic import episode_columns, write_training_folder
from tests.logs.samples import csv_text, write


@pytest.fixture
def cache(tmp_path):
    return tmp_path / "cache"


def test_round_trip_writer_to_frame(tmp_path, cache):
    rng = np.random.default_rng(0)
    cols = episode_columns(np.arange(4), np.array([5, 3, 8, 2]), rng)
    with SimtraceWriter(training_simtrace_path(tmp_path, 0)) as w:
        w.write(cols)
    df = load(tmp_path, cache_dir=cache)
    assert list(df.columns) == list(FRAME_COLUMNS)
    assert len(df) == 18
    np.testing.assert_allclose(df["x"], np.round(cols["X"], 4))
    np.testing.assert_allclose(df["yaw"], np.round(cols["yaw"], 4))
    np.testing.assert_allclose(df["steering_angle"], cols["steer"])
    np.testing.assert_allclose(df["tstamp"], np.round(cols["tstamp"], 3))
    np.testing.assert_allclose(df["wall_clock"], np.round(cols["wall_clock"], 4))
    assert df["action"].tolist() == cols["action"].tolist()
    assert df["episode_status"].astype(str).tolist() == cols["episode_status"].tolist()
    assert df["on_track"].tolist() == cols["all_wheels_on_track"].tolist()
    assert df["unique_episode"].tolist() == cols["episode"].tolist()


def test_interleaved_rows_are_sorted_by_episode_and_step(tmp_path, cache):
    rng = np.random.default_rng(1)
    cols = episode_columns(np.arange(3), np.array([4, 4, 4]), rng)
    shuffled = rng.permutation(12)
    with SimtraceWriter(training_simtrace_path(tmp_path, 0)) as w:
        w.write({k: np.asarray(v)[shuffled] for k, v in cols.items()})
    df = load(tmp_path, cache_dir=cache)
    assert df["episode"].tolist() == [0] * 4 + [1] * 4 + [2] * 4
    assert df["steps"].tolist() == [1, 2, 3, 4] * 3


def test_multi_worker_unique_episodes_and_iterations(tmp_path, cache):
    write_training_folder(tmp_path / "m", iterations=3, episodes_per_worker=2, workers=3, mean_steps=8)
    df = load(tmp_path / "m", cache_dir=cache)
    firsts = df.groupby("unique_episode")[["iteration", "worker", "episode"]].first()
    assert len(firsts) == 18 and firsts.index.tolist() == list(range(18))
    # iteration-major, then worker, then the worker's own episode number (as deepracer-utils numbers them)
    assert firsts["iteration"].tolist() == [i for i in range(3) for _ in range(6)]
    assert firsts["worker"].tolist() == [w for _ in range(3) for w in range(3) for _ in range(2)]
    assert firsts["episode"].tolist() == [i * 2 + e for i in range(3) for _ in range(3) for e in range(2)]


def test_sampled_episodes_keep_unique_ids(tmp_path, cache):
    rng = np.random.default_rng(2)
    for it in range(3):
        cols = episode_columns(np.arange(it * 6, it * 6 + 6), np.full(6, 3), rng)
        with SimtraceWriter(training_simtrace_path(tmp_path, it), sample_episodes=4) as w:
            w.write(cols)
    df = load(tmp_path, cache_dir=cache)
    assert sorted(set(df["episode"])) == [0, 4, 8, 12, 16]
    assert df.groupby("unique_episode")["episode"].first().tolist() == [0, 4, 8, 12, 16]


def test_evaluations_of_a_model_folder(tmp_path, cache):
    write_training_folder(tmp_path, iterations=1, episodes_per_worker=2, mean_steps=6)
    rng = np.random.default_rng(3)
    for stamp in ("20260101120000", "20260101130000"):
        ev = evaluation_dir(tmp_path, stamp)
        with SimtraceWriter(eval_simtrace_path(ev)) as w:
            w.write(episode_columns(np.arange(3), np.array([4, 5, 6]), rng))
    train = load(tmp_path, cache_dir=cache)
    assert "stream" not in train.columns and len(train.groupby("unique_episode")) == 2
    ev = load(tmp_path, "evaluation", cache_dir=cache)
    assert len(ev) == 30 and ev["stream"].astype(str).unique().tolist() == ["20260101120000", "20260101130000"]
    assert ev["unique_episode"].max() == 5


def test_upload_folder_with_evaluations_only(tmp_path, cache):
    write(tmp_path / "model" / "model_metadata.json", "{}")
    write(tmp_path / "evaluation-20240101000000" / "evaluation-simtrace" / "0-iteration.csv", csv_text([0, 1]))
    df = load(tmp_path, cache_dir=cache)
    assert df.attrs["kind"] == "evaluation" and len(df) == 6 and set(df["stream"]) == {"20240101000000"}


def test_droa_console_folder_with_csvs(tmp_path, cache):
    base = tmp_path / "sim-trace"
    write(base / "training" / "2025-01-01T00-00-00Z" / "training-simtrace" / "0-iteration.csv", csv_text([0, 1]))
    write(base / "training" / "2025-01-01T00-00-00Z" / "training-simtrace" / "1-iteration.csv", csv_text([2]))
    write(base / "evaluation" / "2025-01-02T00-00-00Z" / "evaluation-simtrace" / "0-iteration.csv", csv_text([0]))
    assert len(load(tmp_path, cache_dir=cache)) == 9
    assert load(tmp_path, "evaluation", cache_dir=cache)["stream"].tolist() == ["2025-01-02T00-00-00Z"] * 3


def test_cache_reload_is_identical_and_picks_up_a_new_iteration(tmp_path, cache):
    folder = tmp_path / "m"
    write_training_folder(folder, iterations=3, episodes_per_worker=2, workers=2, mean_steps=6)
    first = load(folder, cache_dir=cache)
    assert len(list(cache.rglob("*.parquet"))) == 1
    again = load(folder, cache_dir=cache)
    pd.testing.assert_frame_equal(first, again)

    rng = np.random.default_rng(9)
    for w in range(2):
        with SimtraceWriter(training_simtrace_path(folder / str(w), 3)) as writer:
            writer.write(episode_columns(np.arange(6, 8), np.array([3, 4]), rng))
    newer = load(folder, cache_dir=cache)
    assert len(newer) == len(first) + 14 and newer["iteration"].max() == 3
    assert newer["unique_episode"].max() == first["unique_episode"].max() + 4
    assert len(list(cache.rglob("*.parquet"))) == 2  # only the new files were parsed
    pd.testing.assert_frame_equal(newer, load(folder, cache=False))


def test_cache_notices_a_rewritten_file(tmp_path, cache):
    write_training_folder(tmp_path, iterations=2, episodes_per_worker=2, mean_steps=6)
    load(tmp_path, cache_dir=cache)
    path = training_simtrace_path(tmp_path, 1)
    rng = np.random.default_rng(4)
    with SimtraceWriter(path) as w:
        w.write(episode_columns(np.arange(2, 4), np.array([2, 2]), rng))
    os.utime(path, ns=(1, 1))  # a different mtime even on a coarse clock
    df = load(tmp_path, cache_dir=cache)
    assert (df["iteration"] == 1).sum() == 4
    pd.testing.assert_frame_equal(df, load(tmp_path, cache=False))


def test_no_cache_writes_nothing(tmp_path, cache):
    write_training_folder(tmp_path / "m", iterations=1, episodes_per_worker=1, mean_steps=4)
    load(tmp_path / "m", cache=False, cache_dir=cache)
    assert not cache.exists()


def test_deepracer_utils_reads_a_folder_written_by_the_writers(tmp_path):
    log_mod = pytest.importorskip("deepracer.logs", reason="deepracer-utils not installed (pip install -e '.[test]')")
    folder = tmp_path / "model"
    write_training_folder(folder, iterations=4, episodes_per_worker=3, mean_steps=10)
    metrics = TrainingMetrics(training_metrics_path(folder))
    metrics.add([{"reward_score": 5, "metric_time": 2000, "start_time": 1000, "elapsed_time_in_milliseconds": 1000,
                  "episode": e, "trial": (e - 1) % 3 + 1, "phase": "training", "completion_percentage": 30,
                  "episode_status": "Off track"} for e in range(1, 13)])
    metrics.save()
    logging.getLogger("deepracer.logs.log").setLevel(logging.ERROR)  # no model_metadata.json here

    log = log_mod.DeepRacerLog(str(folder))
    log.load()
    theirs = log.dataframe()
    ours = load(folder, cache=False)
    assert len(theirs) == len(ours) > 0
    for col in theirs.columns:
        a, b = theirs[col].to_numpy(), ours[col].to_numpy()
        if a.dtype.kind in "fiub":
            np.testing.assert_allclose(a.astype(float), b.astype(float), err_msg=col)
        else:
            assert (a.astype(str) == b.astype(str)).all(), col

    tm = log_mod.TrainingMetrics(None, fname=str(training_metrics_path(folder)))
    assert tm.metrics["iteration"].tolist() == [e // 3 for e in range(12)]


def test_a_single_csv_file(tmp_path, cache):
    path = write(tmp_path / "downloads" / "7-iteration.csv", csv_text([0, 1]))
    df = load(path, cache_dir=cache)
    assert len(df) == 6 and set(df["iteration"]) == {7}
    other = write(tmp_path / "trace.csv", csv_text([0]))
    assert len(load(other, cache_dir=cache)) == 3


def test_many_reloads_compact_the_cache(tmp_path, cache):
    rng = np.random.default_rng(5)
    for it in range(15):
        with SimtraceWriter(training_simtrace_path(tmp_path, it)) as w:
            w.write(episode_columns(np.array([it]), np.array([3]), rng))
        df = load(tmp_path, cache_dir=cache)
    assert len(df) == 45 and df["unique_episode"].max() == 14
    assert len(list(cache.rglob("*.parquet"))) <= 13
    pd.testing.assert_frame_equal(df, load(tmp_path, cache=False))


def test_stale_orphan_segments_are_removed(tmp_path, cache):
    write_training_folder(tmp_path / "m", iterations=1, episodes_per_worker=1, mean_steps=4)
    load(tmp_path / "m", cache_dir=cache)
    folder = next(cache.iterdir())
    orphan = folder / "segment-000000000000.parquet"
    orphan.write_bytes(b"x")
    os.utime(orphan, (1, 1))
    load(tmp_path / "m", cache_dir=cache)
    assert not orphan.exists()


def test_unknown_kind_and_missing_path_are_refused(tmp_path):
    with pytest.raises(ValueError, match="kind"):
        load(tmp_path, "races")
    with pytest.raises(LogFileError, match="nowhere: no such file or folder"):
        load(tmp_path / "nowhere")


def test_load_metrics_training_workers_and_evaluations(tmp_path):
    for worker in (0, 1):
        m = TrainingMetrics(training_metrics_path(tmp_path, worker))
        m.add([{"reward_score": 1, "metric_time": 2, "start_time": 1, "elapsed_time_in_milliseconds": 1,
                "episode": e, "trial": (e - 1) % 4 + 1, "phase": "training", "completion_percentage": 10,
                "episode_status": "Off track"} for e in range(1, 9)])
        m.save()
    df = load_metrics(tmp_path)
    assert len(df) == 16 and sorted(set(df["worker"])) == [0, 1]
    assert df.loc[df["worker"] == 0, "iteration"].tolist() == [0, 0, 0, 0, 1, 1, 1, 1]
    ev = EvalMetrics(evaluation_dir(tmp_path, "20260101000000") / "EvalMetrics.json")
    ev.add([{"completion_percentage": 100, "metric_time": 2, "start_time": 1, "elapsed_time_in_milliseconds": 9000,
             "episode_status": "Lap complete", "crash_count": 0, "immobilized_count": 0, "off_track_count": 0,
             "reversed_count": 0, "reset_count": 0, "trial": t} for t in (1, 2, 3)])
    ev.save()
    evals = load_metrics(tmp_path, "evaluation")
    assert evals["stream"].tolist() == ["20260101000000"] * 3 and evals["trial"].tolist() == [1, 2, 3]
    with pytest.raises(LogFileError, match="no EvalMetrics.json"):
        load_metrics(tmp_path / "metrics", "evaluation")


def test_rows_with_absurd_coordinates_are_dropped_with_one_warning(tmp_path, cache):
    rng = np.random.default_rng(1)
    cols = episode_columns(np.arange(3), np.array([6, 4, 5]), rng)
    cols["X"] = np.asarray(cols["X"], dtype=np.float64).copy()
    cols["X"][2] = 1e308  # a forged or damaged row
    with SimtraceWriter(training_simtrace_path(tmp_path, 0)) as w, np.errstate(over="ignore"):
        w.write(cols)
    with pytest.warns(UserWarning) as caught:
        df = load(tmp_path, cache_dir=cache)
    assert len(caught) == 1
    msg = str(caught[0].message)
    assert str(tmp_path) in msg and "dropped 1 simtrace row" in msg and "x=1e+308" in msg
    assert len(df) == 14 and df.attrs["dropped_rows"] == 1 and df["x"].abs().max() < 1e4
