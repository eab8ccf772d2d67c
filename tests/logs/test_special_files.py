"""Log folders are data from anyone: pipes, devices, links to /dev/zero and gzip bombs among their files are left out
or refused in one line, never waited on or read without end (`racerlab.logs.files`, the check every reader makes)."""

from __future__ import annotations

import gzip
import io
import os
import re
import subprocess
import sys
import tarfile
import warnings
from pathlib import Path

import pytest

import racerlab
from racerlab.logs import LogFileError, load, load_metrics
from racerlab.logs.metrics import read_metrics_document
from racerlab.logs.sources import DirStore
from racerlab.logs.synthetic import write_training_folder

pytestmark = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
SRC = str(Path(racerlab.__file__).parents[1])


def _racerlab(args: list[str], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    """The command in a fresh process, so that a read that blocks fails the test at the timeout, not for ever."""
    code = "import sys; from racerlab.cli import main; sys.exit(main(sys.argv[1:]))"
    env = {**os.environ, "PYTHONPATH": SRC, "RACERLAB_CACHE_DIR": str(cwd / "cache")}
    return subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


def _hostile(folder: Path) -> None:
    """What issue 45 put into log folders: a FIFO named like a simtrace and like a robomaker log, a link to /dev/zero
    named like a simtrace, a device-like link, a broken link."""
    os.mkfifo(folder / "7-iteration.csv")
    os.mkfifo(folder / "x-robomaker.log")
    (folder / "8-iteration.csv").symlink_to("/dev/zero")
    (folder / "9-iteration.csv.gz").symlink_to(folder / "gone")


@pytest.mark.parametrize("command", ["calibrate", "report"])
def test_a_fifo_named_like_a_simtrace_returns_within_seconds_with_one_line(tmp_path, command):
    """Issue 45, item 2: `mkdir d; mkfifo d/0-iteration.csv; racerlab calibrate d` (or report) hung."""
    (tmp_path / "d").mkdir()
    os.mkfifo(tmp_path / "d" / "0-iteration.csv")
    out = _racerlab([command, "d"], tmp_path)
    lines = out.stderr.strip().splitlines()
    lines = [line for line in lines if not line.startswith("report: ")]  # the report's progress lines
    assert out.returncode == 2 and len(lines) == 1, out.stderr
    assert "found no step logs" in lines[0] and "0-iteration.csv (a pipe (FIFO))" in lines[0]


def test_a_report_of_a_folder_with_pipes_and_devices_reads_the_rest(tmp_path):
    """The FIFOs and links sit beside real logs, and the report's own side files are pipes too: the report is
    written from what can be read, with one line naming what was left out."""
    folder = tmp_path / "drfc"
    write_training_folder(folder, iterations=2, episodes_per_worker=3)
    _hostile(folder / "training-simtrace")
    (folder / "metrics").mkdir()
    os.mkfifo(folder / "metrics" / "TrainingMetrics.json")
    os.mkfifo(folder / "training.toml")
    (folder / "evaluation-20240101000000").mkdir()
    os.mkfifo(folder / "evaluation-20240101000000" / "summary.json")
    out = _racerlab(["report", "drfc", "--out", "r.html"], tmp_path)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "r.html").stat().st_size > 10_000
    warned = [line for line in out.stderr.splitlines() if line.startswith("racerlab: warning: ")]
    assert len(warned) == 2, out.stderr  # the step logs' folder (all seven), then the metrics files
    assert "drfc: skipped 7 entries that are not a regular file: " in warned[0] and "..." in warned[0]
    assert "TrainingMetrics.json (a pipe (FIFO))" in warned[1]


def test_a_folder_walk_keeps_regular_files_only(tmp_path):
    from racerlab.logs import files

    write_training_folder(tmp_path, iterations=1, episodes_per_worker=2)
    _hostile(tmp_path / "training-simtrace")
    store = DirStore(tmp_path)
    assert list(store.files()) == ["training-simtrace/0-iteration.csv"]
    assert sorted(rel for rel, _ in store.skipped.found) == [
        "training-simtrace/7-iteration.csv", "training-simtrace/8-iteration.csv",
        "training-simtrace/9-iteration.csv.gz", "training-simtrace/x-robomaker.log"]
    with pytest.warns(files.SkippedFilesWarning, match="skipped 4 entries"):
        df = load(tmp_path, cache=False)
    assert df["unique_episode"].nunique() == 2


@pytest.mark.parametrize("path, words", [("fifo", "a pipe (FIFO)"), ("/dev/zero", "a device")])
def test_a_path_given_that_is_no_file_is_one_line(tmp_path, path, words):
    os.mkfifo(tmp_path / "fifo")
    where = tmp_path / path if path == "fifo" else Path(path)
    with pytest.raises(LogFileError, match=re.escape(f"not a file or a folder ({words})")) as err:
        load(where, cache=False)
    assert "\n" not in str(err.value)
    with pytest.raises(LogFileError, match=re.escape(words)):
        read_metrics_document(where)  # opened without blocking: refused, not waited on


def test_a_gzip_that_expands_past_the_limit_is_one_line(tmp_path, monkeypatch):
    """Issue 45, item 2: a gzip that expands to gigabytes ended in MemoryError. The limit is lowered here to 4 MiB,
    and 64 MiB of zeros compressed to 64 kB stand for the bomb."""
    from racerlab.logs import files

    monkeypatch.setattr(files, "MAX_LOG_BYTES", 4 << 20, raising=False)
    write_training_folder(tmp_path, iterations=1, episodes_per_worker=2)
    bomb = tmp_path / "training-simtrace" / "1-iteration.csv.gz"
    bomb.write_bytes(gzip.compress(b"\0" * (64 << 20), 9))
    assert bomb.stat().st_size < 200_000
    with pytest.raises(LogFileError, match=r"1-iteration\.csv\.gz: expands to more than 0\.00390625 GiB") as err:
        load(tmp_path, cache=False)
    assert "\n" not in str(err.value)


def test_plain_files_and_archive_members_past_the_limit_are_one_line(tmp_path, monkeypatch):
    from racerlab.logs import files

    monkeypatch.setattr(files, "MAX_LOG_BYTES", 1 << 20, raising=False)
    big = tmp_path / "big" / "0-iteration.csv"
    big.parent.mkdir()
    big.write_bytes(b"x" * (2 << 20))
    with pytest.raises(LogFileError, match=r"0-iteration\.csv: is more than"):
        load(big.parent, cache=False)
    archive = tmp_path / "export.tar.gz"
    with tarfile.open(archive, "w:gz") as tar:
        info = tarfile.TarInfo("sim-trace/training/training-simtrace/0-iteration.csv")
        info.size = 2 << 20
        tar.addfile(info, io.BytesIO(b"x" * info.size))
    with pytest.raises(LogFileError, match=r"export\.tar\.gz:sim-trace/training/training-simtrace/0-iteration\.csv: "
                                           r"2\.0 GiB|export\.tar\.gz:.*more than racerlab reads"):
        load(archive, cache=False)


def test_metrics_files_that_are_no_files_are_left_out(tmp_path):
    (tmp_path / "metrics").mkdir()
    (tmp_path / "metrics" / "TrainingMetrics.json").write_text(
        '{"metrics": [{"reward_score": 1, "metric_time": 1, "start_time": 0, "elapsed_time_in_milliseconds": 1, '
        '"episode": 1, "trial": 1, "phase": "training", "completion_percentage": 10, "episode_status": "Off track"}]}')
    os.mkfifo(tmp_path / "metrics" / "TrainingMetrics_1.json")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        df = load_metrics(tmp_path)
    assert len(df) == 1 and any("TrainingMetrics_1.json (a pipe (FIFO))" in str(w.message) for w in caught)


def test_gunzip_reads_appended_members_and_trailing_zeros_and_refuses_a_cut_one():
    from racerlab.logs import files

    data = gzip.compress(b"a\n") + gzip.compress(b"b\n") + b"\0" * 8
    assert files.gunzip(data, "x.gz") == b"a\nb\n" == gzip.decompress(data)
    with pytest.raises(LogFileError, match="cut short"):
        files.gunzip(gzip.compress(b"a" * 1000)[:-12], "x.gz")
    assert files.gunzip(gzip.compress(b"a\n") + b"\x1f\x8b\x08garbage", "x.gz", torn_ends=True) == b"a\n"
