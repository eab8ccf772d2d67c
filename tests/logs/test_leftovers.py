"""Temporary files in one place, removed on any exit: a `with` block's folder goes when the block ends, and what
a killed process left (its scratch folders, its atomic writes' temporary files) goes the next time racerlab
writes there, while a live process's files stay."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from racerlab.logs import atomic_write_text, scratch_dir
from racerlab.logs.scratch import owner_pid, scratch_root


def _dead_pid() -> int:
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    return gone.pid


@pytest.fixture
def tmpdir_env(tmp_path, monkeypatch):
    monkeypatch.setenv("RACERLAB_TMPDIR", str(tmp_path))
    return tmp_path


def test_a_scratch_folder_is_private_and_removed_when_its_block_ends(tmpdir_env):
    with pytest.raises(RuntimeError):
        with scratch_dir("import") as d:
            (d / "big.bin").write_bytes(bytes(1000))
            assert d.parent == scratch_root() and d.parent.parent == tmpdir_env
            assert oct(d.parent.stat().st_mode & 0o777) == "0o700"
            raise RuntimeError("interrupted")
    assert not d.exists()


def test_a_killed_processes_scratch_folders_are_swept_and_live_ones_kept(tmpdir_env):
    root = scratch_root()
    dead = root / f"s3-push-pid{_dead_pid()}-a1b2c3"
    (dead / "model").mkdir(parents=True)
    (dead / "model" / "model_3.pb").write_bytes(bytes(1000))
    live_proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        live = root / f"import-pid{live_proc.pid}-x9y8z7"
        live.mkdir()
        with scratch_dir("import"):
            pass
        assert not dead.exists() and live.is_dir()
    finally:
        live_proc.kill()
        live_proc.wait()


def test_a_killed_writers_temporary_file_goes_when_the_folder_is_next_written(tmp_path):
    stale = tmp_path / f".0-iteration.csv.tmp-{_dead_pid()}-0a1b2c3d"
    stale.write_bytes(b"")  # the empty simtrace temporary a kill -9 leaves
    mine = tmp_path / f".metrics.json.tmp-{os.getpid()}-00000000"  # a live writer's (ours)
    mine.write_bytes(b"{")
    atomic_write_text(tmp_path / "metrics.json", "{}\n")
    assert not stale.exists() and mine.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [mine.name, "metrics.json"]


@pytest.mark.parametrize("name, pid", [("import-pid123-ab_c9", 123), ("s3-push-pid77-zz", 77),
                                       (".model-1.pb.part-4242-x1", 4242), (".a-b.csv.tmp-9-0f0f", 9),
                                       ("model-1.pb", None), ("notes.txt", None)])
def test_owner_pids_are_read_from_the_names(name, pid):
    assert owner_pid(name) == pid


def test_a_simtrace_that_meets_a_full_disk_leaves_no_temporary_file(tmp_path, monkeypatch):
    import errno

    from racerlab.logs import SimtraceWriter
    from tests.logs.test_simtrace import as_columns, one_row

    path = tmp_path / "training-simtrace" / "3-iteration.csv"
    w = SimtraceWriter(path)
    w.write(as_columns([one_row()] * 10))

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError) as err:
        w.close()
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(path)
    assert list(path.parent.iterdir()) == []
