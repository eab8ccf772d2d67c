"""The command line against clumsy input and a full disk: one line each, never a traceback, nothing lost."""

from __future__ import annotations

import errno
import os
import subprocess
import sys

import pytest

from racerlab.cli import main
from racerlab.model import ModelFolder, init_model


@pytest.mark.parametrize("command", ["evaluate", "race"])
def test_help_of_commands_with_race_flags_prints(command, capsys):
    with pytest.raises(SystemExit) as done:
        main([command, "--help"])
    assert done.value.code == 0
    assert "% of the lap" in capsys.readouterr().out


def test_a_full_disk_is_one_line_and_the_last_iteration_survives(tmp_path, capsys, monkeypatch):
    model = init_model(tmp_path / "m", track="lab_oval", num_cars=4)
    assert main(["train", str(model.path), "--iterations", "1"]) == 0
    before = [c.name for c in model.checkpoints()]
    capsys.readouterr()

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)  # every file racerlab makes durable now meets a full disk
    assert main(["train", str(model.path), "--iterations", "2"]) == 2
    err = capsys.readouterr().err
    assert "No space left on device" in err and "free some disk space" in err and err.count("\n") == 1, err
    monkeypatch.undo()
    assert [c.name for c in model.checkpoints()] == before
    assert not [p for p in model.path.rglob("*") if ".tmp-" in p.name]  # no half-written files left behind
    state = ModelFolder(model.path).load_checkpoint(model.checkpoints()[-1])
    assert state["iteration"] == 1
    assert main(["train", str(model.path), "--iterations", "2"]) == 0  # space again: resumes
    assert model.checkpoints()[-1].iteration == 3  # iteration 1 kept, two more on top


def test_a_short_console_token_is_refused(tmp_path, capsys, monkeypatch):
    uvicorn = pytest.importorskip("uvicorn")

    def serving(*a, **kw):
        raise AssertionError("the console was served with a one-character token")

    monkeypatch.setattr(uvicorn, "run", serving)
    assert main(["console", "--dir", str(tmp_path), "--host", "0.0.0.0", "--token", "a", "--no-browser"]) == 2
    err = capsys.readouterr().err
    assert "--token" in err and "at least 16" in err and err.count("\n") == 1


def test_ctrl_c_stops_a_race_at_once_with_one_line_saying_what_stays(tmp_path):
    """Issue 28, case 13: a long race could only be killed. Ctrl-C ends it within a lap: exit status 130, the
    finished models' evaluations kept, no leaderboard."""
    import signal
    import time

    from racerlab.logs import evaluation_dirs
    from tests.evaluate.models import write_checkpoint, write_model

    dirs = []
    for name in ("a", "b", "c"):
        folder = write_model(tmp_path / name, "lab_oval", actions=((0.0, 1.0), (15.0, 1.0)))
        write_checkpoint(folder)
        dirs.append(str(folder.path))
    import racerlab

    env = {**os.environ, "PYTHONPATH": os.path.dirname(os.path.dirname(os.path.abspath(racerlab.__file__)))}
    out = tmp_path / "board.json"
    proc = subprocess.Popen([sys.executable, "-m", "racerlab", "race", *dirs, "--trials", "300", "--out", str(out)],
                            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=env)
    try:
        for line in proc.stderr:  # the first model's result: it is done, the second one is on the track
            if line.startswith("a: "):
                break
        time.sleep(0.2)  # b's 300 trials take ~8 s here (~30 ms each); a fast machine still has seconds of them left
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(timeout=30)
        took = time.monotonic() - t0
        rest = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert rc == 130 and took < 5.0, (rc, took)
    assert rest.strip().splitlines()[-1] == ("racerlab: race interrupted after 1 of 3 models: the evaluations of a "
                                             "are kept in their model folders; no leaderboard was written")
    assert "Traceback" not in rest
    assert len(evaluation_dirs(dirs[0])) == 1 and evaluation_dirs(dirs[1]) == [] and not out.exists()
