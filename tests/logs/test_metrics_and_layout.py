"""AWS metrics JSON, metrics.jsonl, atomic writes and the model-folder paths deepracer-utils expects."""

from __future__ import annotations

import json
from datetime import datetime

import pytest

from racerlab.logs import (
    EvalMetrics,
    LogFileError,
    MetricsLog,
    TrainingMetrics,
    atomic_write_json,
    atomic_write_text,
    eval_metrics_path,
    eval_simtrace_path,
    evaluation_dir,
    evaluation_dirs,
    export_drfc_metadata,
    follow_metrics_jsonl,
    last_metrics_entry,
    metrics_jsonl_path,
    new_evaluation_dir,
    read_metrics_jsonl,
    remove_training_simtrace_after,
    simtrace_files,
    training_metrics_path,
    training_simtrace_path,
)


def training_entry(episode: int, phase: str = "training") -> dict:
    return {"reward_score": 12, "metric_time": 1000 + episode, "start_time": 900, "elapsed_time_in_milliseconds": 100,
            "episode": episode, "trial": (episode - 1) % 20 + 1, "phase": phase, "completion_percentage": 42,
            "episode_status": "Off track"}


def test_training_metrics_document_and_resume(tmp_path):
    path = training_metrics_path(tmp_path)
    m = TrainingMetrics(path, best_model_metric="laptime")
    m.add([training_entry(1), training_entry(2), training_entry(2, "evaluation")])
    m.save()
    doc = json.loads(path.read_text())
    assert doc["version"] == 2.0 and doc["best_model_metric"] == "laptime"
    assert list(doc["metrics"][0]) == ["reward_score", "metric_time", "start_time", "elapsed_time_in_milliseconds",
                                       "episode", "trial", "phase", "completion_percentage", "episode_status"]
    resumed = TrainingMetrics(path, best_model_metric="laptime")
    assert len(resumed) == 3
    resumed.truncate(1)
    resumed.add([training_entry(2)])
    resumed.save()
    assert [e["episode"] for e in json.loads(path.read_text())["metrics"]] == [1, 2]


def test_training_metrics_refuses_wrong_keys_and_metric(tmp_path):
    m = TrainingMetrics(tmp_path / "t.json")
    bad = training_entry(1)
    del bad["trial"]
    with pytest.raises(ValueError, match="trial"):
        m.add([bad])
    with pytest.raises(ValueError, match="best_model_metric"):
        TrainingMetrics(tmp_path / "t.json", best_model_metric="speed")


def test_garbled_metrics_file_is_a_one_line_error(tmp_path):
    path = tmp_path / "TrainingMetrics.json"
    path.write_text('{"metrics": [')
    with pytest.raises(LogFileError, match="TrainingMetrics.json: not valid JSON"):
        TrainingMetrics(path)


def test_eval_metrics_schema(tmp_path):
    path = eval_metrics_path(tmp_path)
    m = EvalMetrics(path)
    m.add([{"completion_percentage": 100, "metric_time": 2, "start_time": 1, "elapsed_time_in_milliseconds": 9001,
            "episode_status": "Lap complete", "crash_count": 0, "immobilized_count": 0, "off_track_count": 1,
            "reversed_count": 0, "reset_count": 1, "trial": 1}])
    m.save()
    doc = json.loads(path.read_text())
    assert set(doc) == {"metrics"} and doc["metrics"][0]["reset_count"] == 1


def test_metrics_jsonl_appends_and_survives_a_torn_line(tmp_path):
    path = metrics_jsonl_path(tmp_path)
    with MetricsLog(path) as log:
        log.append({"iteration": 0, "loss": 1.5})
        log.append({"iteration": 1, "loss": float("nan")})
    with open(path, "a") as f:
        f.write('{"iteration": 2, "lo')  # killed mid-write
    assert read_metrics_jsonl(path) == [{"iteration": 0, "loss": 1.5}, {"iteration": 1, "loss": None}]
    with MetricsLog(path) as log:  # appending repairs the torn tail first
        log.append({"iteration": 2})
    assert [e["iteration"] for e in read_metrics_jsonl(path)] == [0, 1, 2]
    log = MetricsLog(path)
    log.truncate(1)
    assert [e["iteration"] for e in log.read()] == [0, 1]


def test_metrics_jsonl_bad_middle_line_names_file_and_line(tmp_path):
    path = tmp_path / "metrics.jsonl"
    path.write_text('{"a": 1}\nnot json\n{"a": 2}\n')
    with pytest.raises(LogFileError, match=r"metrics.jsonl:2: not valid JSON"):
        read_metrics_jsonl(path)


def test_following_a_metrics_jsonl_as_it_is_written(tmp_path):
    """The console's chart reads each new complete line once; a line still being written waits for its newline."""
    path = tmp_path / "metrics.jsonl"
    assert follow_metrics_jsonl(path, 0) == ([], 0) and last_metrics_entry(path) is None  # no training yet
    first = '{"iteration": 1}\n'
    path.write_text(first + '{"iteration": 2')
    entries, offset = follow_metrics_jsonl(path, 0)
    assert entries == [{"iteration": 1}] and offset == len(first)
    assert last_metrics_entry(path) == {"iteration": 1}
    with open(path, "a") as f:
        f.write(', "x": 3}\nnot json\n{"iteration": 3}\n')
    entries, offset = follow_metrics_jsonl(path, offset)
    assert entries == [{"iteration": 2, "x": 3}, {"iteration": 3}] and offset == path.stat().st_size
    assert last_metrics_entry(path) == {"iteration": 3}
    assert last_metrics_entry(path, tail_bytes=10) is None  # a tail cut mid-line holds no whole entry
    assert follow_metrics_jsonl(path, offset) == ([], offset)


def test_atomic_writes_leave_no_temp_files(tmp_path):
    atomic_write_text(tmp_path / "a" / "x.txt", "hello")
    atomic_write_json(tmp_path / "a" / "y.json", {"k": 1})
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["x.txt", "y.json"]
    with pytest.raises(ValueError):
        atomic_write_json(tmp_path / "a" / "z.json", {"k": float("nan")})
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["x.txt", "y.json"]


def test_paths_follow_the_drfc_single_worker_layout(tmp_path):
    assert training_simtrace_path(tmp_path, 12) == tmp_path / "training-simtrace" / "12-iteration.csv"
    assert training_simtrace_path(tmp_path, 3, compress=True).name == "3-iteration.csv.gz"
    assert training_metrics_path(tmp_path) == tmp_path / "metrics" / "TrainingMetrics.json"
    assert training_metrics_path(tmp_path, 2).name == "TrainingMetrics_2.json"
    assert metrics_jsonl_path(tmp_path) == tmp_path / "metrics" / "metrics.jsonl"
    ev = evaluation_dir(tmp_path, datetime(2026, 1, 2, 3, 4, 5))
    assert ev == tmp_path / "evaluation-20260102030405"
    assert eval_simtrace_path(ev) == ev / "evaluation-simtrace" / "0-iteration.csv"
    with pytest.raises(ValueError):
        training_simtrace_path(tmp_path, -1)


def test_new_evaluation_dirs_are_unique_and_listed(tmp_path):
    when = datetime(2026, 1, 2, 3, 4, 5)
    a = new_evaluation_dir(tmp_path, when)
    b = new_evaluation_dir(tmp_path, when)
    assert a.name == "evaluation-20260102030405" and b.name == "evaluation-20260102030406"
    assert evaluation_dirs(tmp_path) == [a, b]


def test_simtrace_files_and_pruning(tmp_path):
    for n in (0, 1, 2, 10):
        atomic_write_text(training_simtrace_path(tmp_path, n, compress=n == 2), "x")
    assert list(simtrace_files(tmp_path / "training-simtrace")) == [0, 1, 2, 10]
    removed = remove_training_simtrace_after(tmp_path, 1)
    assert sorted(p.name for p in removed) == ["10-iteration.csv", "2-iteration.csv.gz"]


def test_export_drfc_metadata_copies_where_deepracer_utils_looks(tmp_path):
    (tmp_path / "model_metadata.json").write_text('{"action_space": []}')
    (tmp_path / "hyperparameters.json").write_text('{"lr": 0.0003}')
    written = export_drfc_metadata(tmp_path)
    assert [p.relative_to(tmp_path).as_posix() for p in written] == ["model/model_metadata.json",
                                                                     "ip/hyperparameters.json"]
