"""The simtrace writer: AWS formats to the character, vectorised == per-row reference, atomic publishing."""

from __future__ import annotations

import gzip
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from racerlab.logs import SIMTRACE_COLUMNS, SimtraceWriter, format_row, format_rows, remove_stale_temps
from racerlab.logs.synthetic import episode_columns


def one_row(**over) -> dict:
    row = {"episode": 7, "steps": 12, "X": 3.05981234, "Y": -0.68864, "yaw": -132.24841, "steer": -30.0,
           "throttle": 0.5, "action": 4, "reward": 1.23456, "done": False, "all_wheels_on_track": True,
           "progress": 7.04649, "closest_waypoint": 11, "track_len": 23.1234, "tstamp": 36.597,
           "episode_status": "in_progress", "pause_duration": 0.0, "obstacle_crash_counter": 0,
           "wall_clock": 1700000000.123456}
    row.update(over)
    return row


def as_columns(rows: list[dict]) -> dict:
    cols = {c: [r[c] for r in rows] for c in SIMTRACE_COLUMNS}
    if isinstance(rows[0]["action"], list | tuple):
        cols["action"] = np.array(cols["action"], dtype=float)
    return cols


def test_columns_are_the_19_aws_names_in_order():
    assert SIMTRACE_COLUMNS == ("episode", "steps", "X", "Y", "yaw", "steer", "throttle", "action", "reward",
                                "done", "all_wheels_on_track", "progress", "closest_waypoint", "track_len",
                                "tstamp", "episode_status", "pause_duration", "obstacle_crash_counter",
                                "wall_clock")


def test_a_row_formatted_by_hand():
    expected = ("7,12,3.0598,-0.6886,-132.2484,-30.00,0.50,4,1.2346,False,True,7.0465,11,23.12,36.597,"
                "in_progress,0.00,0,1700000000.1235\n")
    assert format_row(one_row()) == expected
    assert format_rows(as_columns([one_row()])).decode() == expected


def test_continuous_action_is_bracketed_steer_space_speed():
    line = format_rows(as_columns([one_row(action=(-12.345, 2.5))])).decode()
    assert line.split(",")[7] == "[-12.35 2.50]"  # %.2f each, no comma inside the field
    assert line.count(",") == 18


def test_tstamp_is_str_of_sim_time_on_a_millisecond_clock():
    cells = [format_rows(as_columns([one_row(tstamp=t)])).decode().split(",")[14]
             for t in (36.5, 36.0, 0.0, 1 / 15, 1234.5678)]
    assert cells == ["36.5", "36.0", "0.0", "0.067", "1234.568"]


def test_edge_values_match_python_percent_formatting():
    xs = [0.00005, -0.00001, -0.0, 2.5e-5, 0.12345, 1e20, float("nan"), float("inf"), -float("inf"), 99999.99995]
    rows = [one_row(X=x, reward=x, steps=i, episode=-i) for i, x in enumerate(xs)]
    got = format_rows(as_columns(rows)).decode().splitlines(keepends=True)
    assert got == [format_row(r) for r in rows]
    assert got[1].split(",")[2] == "-0.0000"  # the sign survives rounding to zero, as with "%.4f"


def test_vectorised_equals_reference_on_random_rows():
    rng = np.random.default_rng(3)
    cols = episode_columns(np.arange(40), rng.integers(2, 80, 40), rng)
    cols["X"] = cols["X"] * 10 ** rng.uniform(-6, 5, len(cols["X"]))
    cols["reward"] = rng.normal(0, 1000, len(cols["X"]))
    cols["tstamp"] = rng.uniform(0, 1e5, len(cols["X"]))
    got = format_rows(cols).decode().splitlines(keepends=True)
    ref = [format_row({c: cols[c][i] for c in SIMTRACE_COLUMNS}) for i in range(len(got))]
    assert got == ref


def test_header_once_across_batches_and_rows_counted(tmp_path):
    path = tmp_path / "0-iteration.csv"
    with SimtraceWriter(path) as w:
        w.write(as_columns([one_row(steps=1)]))
        w.write(as_columns([one_row(steps=2), one_row(steps=3)]))
    lines = path.read_text().splitlines()
    assert lines[0] == ",".join(SIMTRACE_COLUMNS)
    assert [ln.split(",")[1] for ln in lines[1:]] == ["1", "2", "3"]
    assert w.rows == 3


def test_empty_file_has_the_header(tmp_path):
    path = SimtraceWriter(tmp_path / "0-iteration.csv").close()
    assert path.read_text() == ",".join(SIMTRACE_COLUMNS) + "\n"


def test_compress_writes_gzip_with_gz_suffix(tmp_path):
    w = SimtraceWriter(tmp_path / "3-iteration.csv", compress=True)
    w.write(as_columns([one_row()]))
    path = w.close()
    assert path.name == "3-iteration.csv.gz"
    assert gzip.decompress(path.read_bytes()).decode().splitlines()[1] == format_row(one_row()).rstrip("\n")


def test_sample_episodes_keeps_every_kth_episode(tmp_path):
    with SimtraceWriter(tmp_path / "0-iteration.csv", sample_episodes=3) as w:
        w.write(as_columns([one_row(episode=e) for e in range(7)]))
    episodes = [ln.split(",")[0] for ln in (tmp_path / "0-iteration.csv").read_text().splitlines()[1:]]
    assert episodes == ["0", "3", "6"]


def test_missing_or_ragged_columns_are_refused(tmp_path):
    w = SimtraceWriter(tmp_path / "0-iteration.csv")
    cols = as_columns([one_row()])
    with pytest.raises(ValueError, match="missing"):
        w.write({k: v for k, v in cols.items() if k != "yaw"})
    cols["yaw"] = [1.0, 2.0]
    with pytest.raises(ValueError, match="differ in length"):
        w.write(cols)
    with pytest.raises(ValueError, match="comma"):
        w.write(as_columns([one_row(episode_status="a,b")]))
    w.abort()


def test_exception_in_with_block_leaves_no_file(tmp_path):
    path = tmp_path / "0-iteration.csv"
    with pytest.raises(RuntimeError), SimtraceWriter(path) as w:
        w.write(as_columns([one_row()]))
        raise RuntimeError("crash")
    assert list(tmp_path.iterdir()) == []


def test_killed_writer_leaves_no_final_file(tmp_path):
    path = tmp_path / "training-simtrace" / "5-iteration.csv"
    script = textwrap.dedent(f"""
        import os, signal
        from racerlab.logs import SimtraceWriter
        from tests.logs.test_simtrace import as_columns, one_row
        w = SimtraceWriter({str(path)!r})
        w.write(as_columns([one_row()] * 1000))
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    proc = subprocess.run([sys.executable, "-c", script], cwd=str(_repo_root()), capture_output=True)
    assert proc.returncode != 0
    assert not path.exists()
    leftovers = remove_stale_temps(path.parent)
    assert len(leftovers) == 1 and leftovers[0].name.startswith(".5-iteration.csv.tmp-")
    assert list(path.parent.iterdir()) == []


def test_close_replaces_an_older_file_whole(tmp_path):
    path = tmp_path / "0-iteration.csv"
    path.write_text("old\n")
    w = SimtraceWriter(path)
    w.write(as_columns([one_row()]))
    assert path.read_text() == "old\n"  # nothing visible until close
    w.close()
    assert path.read_text().splitlines()[1].startswith("7,12,")


def _repo_root():
    from pathlib import Path
    return Path(__file__).resolve().parents[2]
