"""The training-simtrace disk budget: gzip past the plain window, thinning past the cap, readers still read."""

from __future__ import annotations

import gzip
import logging
import shutil

import numpy as np
import pandas as pd
import pytest

from racerlab.analysis import load
from racerlab.logs import SimtraceRetention, SimtraceWriter, thin_simtrace, training_simtrace_path
from racerlab.logs.synthetic import episode_columns

HEADER = b"episode,steps,X\n"


def _rows(*episodes: int) -> bytes:
    return HEADER + b"".join(b"%d,%d,0.5\n" % (e, s) for e in episodes for s in (1, 2))


def test_a_thinning_halves_consecutive_episodes_then_removes_the_file():
    once = thin_simtrace(_rows(4, 5, 6, 7))
    assert once == _rows(4, 6)  # every episode divides by 2**0: keep multiples of 2
    assert thin_simtrace(once) == _rows(4)  # all divide by 2**1: keep multiples of 4
    assert thin_simtrace(_rows(4)) is None  # 4 is not a multiple of 8: nothing left


def test_episode_0_is_never_thinned_away():
    assert thin_simtrace(_rows(0, 3)) == _rows(0)
    only_zero = _rows(0)
    assert thin_simtrace(only_zero) == only_zero


EPISODES_PER_ITERATION = 8


def _write_iterations(folder, first: int, count: int, retention: SimtraceRetention | None, sizes: list[int]):
    """Iterations first..first+count-1 of 8 episodes (global numbering), enforcing after each."""
    originals = {}
    for it in range(first, first + count):
        episodes = np.arange(it * EPISODES_PER_ITERATION, (it + 1) * EPISODES_PER_ITERATION)
        cols = episode_columns(episodes, np.full(len(episodes), 40), np.random.default_rng(it))
        path = training_simtrace_path(folder, it)
        with SimtraceWriter(path) as w:
            w.write(cols)
        originals[it] = cols
        if retention is not None:
            retention.added(it, path)
            retention.enforce()
            sizes.append(sum(p.stat().st_size for p in path.parent.iterdir()))
    return originals


def test_writing_past_the_cap_keeps_the_folder_under_it_and_every_kept_row_readable(tmp_path):
    folder = tmp_path / "training-simtrace"
    plain_file = training_file_size(tmp_path)
    cap = 12 * plain_file  # room for 1 + 3 plain files and some gzipped history
    retention = SimtraceRetention(folder, plain=3, max_bytes=cap)
    sizes: list[int] = []
    originals = _write_iterations(tmp_path, 0, 120, retention, sizes)
    assert max(sizes) <= cap
    names = sorted(p.name for p in folder.iterdir())
    plain = sorted(int(n.split("-")[0]) for n in names if n.endswith(".csv"))
    assert plain == [0, 117, 118, 119]  # iteration 0 (deepracer-utils counts episodes from it) + newest 3
    assert all(n.endswith((".csv", ".csv.gz")) for n in names)

    df = load(tmp_path, cache=False)
    kept = df.groupby("episode").size()
    whole = np.arange(120 * EPISODES_PER_ITERATION)
    # the newest plain iterations and iteration 0 are complete; the history is thinned to whole episodes
    assert set(range(117 * EPISODES_PER_ITERATION, 120 * EPISODES_PER_ITERATION)) <= set(kept.index)
    assert set(range(EPISODES_PER_ITERATION)) <= set(kept.index)
    assert (kept == 40).all()  # every kept episode kept all its steps
    assert len(kept) < len(whole) / 2  # and the cap really forced thinning
    gaps = np.diff(np.array(sorted(e for e in kept.index if EPISODES_PER_ITERATION <= e < 100 * 8)))
    assert gaps.max() <= 8 * gaps.min()  # evenly spaced, denser toward the newest
    # every kept row is the row that was written
    for it in (1, 50, 110, 119):
        cols = originals[it]
        mine = df[df["iteration"] == it].sort_values(["episode", "steps"])
        mask = np.isin(cols["episode"], mine["episode"].unique())
        np.testing.assert_allclose(mine["x"].to_numpy(), np.round(cols["X"][mask], 4))


def training_file_size(tmp_path) -> int:
    """Size of one plain iteration file as the test writes them (8 episodes of 40 steps)."""
    probe = tmp_path / "probe"
    _write_iterations(probe, 5, 1, None, [])
    size = training_simtrace_path(probe, 5).stat().st_size
    shutil.rmtree(probe)
    return size


def test_without_a_cap_older_iterations_are_gzipped_and_nothing_is_dropped(tmp_path):
    retention = SimtraceRetention(tmp_path / "training-simtrace", plain=2, max_bytes=0)
    _write_iterations(tmp_path, 0, 6, retention, [])
    names = sorted(p.name for p in (tmp_path / "training-simtrace").iterdir())
    assert names == ["0-iteration.csv", "1-iteration.csv.gz", "2-iteration.csv.gz", "3-iteration.csv.gz",
                     "4-iteration.csv", "5-iteration.csv"]
    df = load(tmp_path, cache=False)
    assert df["episode"].nunique() == 6 * EPISODES_PER_ITERATION and len(df) == 6 * 8 * 40


def test_a_compaction_stopped_halfway_is_finished_on_the_next_scan(tmp_path):
    _write_iterations(tmp_path, 0, 3, None, [])
    plain = training_simtrace_path(tmp_path, 1)
    plain.with_name(plain.name + ".gz").write_bytes(gzip.compress(plain.read_bytes()))  # killed before unlink
    retention = SimtraceRetention(tmp_path / "training-simtrace", plain=5, max_bytes=0)
    assert retention.files[1].name == "1-iteration.csv.gz" and not plain.exists()
    assert load(tmp_path, cache=False)["episode"].nunique() == 3 * EPISODES_PER_ITERATION  # no duplicates


def test_deepracer_utils_reads_the_plain_part(tmp_path):
    log_mod = pytest.importorskip("deepracer.logs", reason="deepracer-utils is a test dependency")
    retention = SimtraceRetention(tmp_path / "training-simtrace", plain=2, max_bytes=6 * training_file_size(tmp_path))
    _write_iterations(tmp_path, 0, 20, retention, [])
    logging.getLogger("deepracer.logs.log").setLevel(logging.ERROR)  # no model_metadata.json here
    log = log_mod.DeepRacerLog(str(tmp_path))
    log.load_training_trace()
    theirs = log.dataframe()
    assert sorted(theirs["iteration"].unique()) == [0, 18, 19]
    ours = load(tmp_path, cache=False)
    mine = ours[ours["iteration"].isin([0, 18, 19])].sort_values(["episode", "steps"]).reset_index(drop=True)
    theirs = theirs.sort_values(["episode", "steps"]).reset_index(drop=True)
    pd.testing.assert_series_equal(theirs["x"], mine["x"], check_names=False)
    assert ours["iteration"].nunique() > 3  # racerlab's reader also reads the gzipped history


# ---- TrainingMetrics.json stays small: the oldest entries move to a gzipped archive -------------------------
def _entry(episode: int) -> dict:
    return {"reward_score": 12, "metric_time": 1000 + episode, "start_time": 900, "elapsed_time_in_milliseconds": 100,
            "episode": episode, "trial": (episode - 1) % 4 + 1, "phase": "training", "completion_percentage": 42,
            "episode_status": "Off track"}


def test_training_metrics_keeps_the_newest_entries_and_archives_the_rest(tmp_path):
    import json

    from racerlab.analysis import load_metrics
    from racerlab.logs import TrainingMetrics, training_metrics_path
    from racerlab.logs.metrics import read_training_archive, training_archive_path

    path = training_metrics_path(tmp_path)
    m = TrainingMetrics(path, keep=3)
    for e in range(1, 21):
        m.add([_entry(e)])
        m.save()
        assert len(json.loads(path.read_text())["metrics"]) <= 6  # never past 2 * keep
    in_file = [e["episode"] for e in json.loads(path.read_text())["metrics"]]
    archived = [e["episode"] for e in read_training_archive(path, [])]
    assert archived + in_file == list(range(1, 21))
    assert load_metrics(tmp_path)["episode"].tolist() == list(range(1, 21))
    assert load_metrics(tmp_path)["iteration"].tolist() == [(e - 1) // 4 for e in range(1, 21)]

    # a crash after archiving, before the file was saved: the entries are in both, read once
    doc = json.loads(path.read_text())
    resumed = TrainingMetrics(path, keep=3)
    resumed.add([_entry(21), _entry(22), _entry(23), _entry(24)])
    resumed.save()
    path.write_text(json.dumps({**doc, "metrics": doc["metrics"] + [_entry(21), _entry(22), _entry(23),
                                                                    _entry(24)]}))
    assert load_metrics(tmp_path)["episode"].tolist() == list(range(1, 25))
    # a torn last gzip member (killed mid-append) ends the archive there
    with open(training_archive_path(path), "ab") as f:
        f.write(gzip.compress(b'{"episode": 99}\n')[:12])
    assert load_metrics(tmp_path)["episode"].tolist() == list(range(1, 25))

    # resuming from an older checkpoint drops archived entries after it too
    again = TrainingMetrics(path, keep=3)
    again.truncate(10)
    again.save()
    assert load_metrics(tmp_path)["episode"].tolist() == list(range(1, 11))


def test_deepracer_utils_reads_a_training_metrics_file_with_archived_entries(tmp_path):
    log_mod = pytest.importorskip("deepracer.logs", reason="deepracer-utils is a test dependency")
    from racerlab.logs import TrainingMetrics, training_metrics_path

    m = TrainingMetrics(training_metrics_path(tmp_path), keep=4)
    for e in range(1, 22):
        m.add([_entry(e)])
        m.save()
    tm = log_mod.TrainingMetrics(None, fname=str(training_metrics_path(tmp_path)))
    # the file's entries keep their AWS numbering: iteration = (episode - 1) // episodes per iteration
    assert tm.metrics["episode"].tolist() == list(range(16, 22))
    assert tm.metrics["iteration"].tolist() == [(e - 1) // 4 for e in range(16, 22)]
