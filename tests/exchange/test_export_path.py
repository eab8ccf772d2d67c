"""`racerlab export -o PATH` writes only what it is asked to: never a model's file, a file it did not write (without
--force), a device or a folder; a folder gets the archive under its default name. Refusals come before anything
is loaded or written."""

from __future__ import annotations

import gzip
import os
import tarfile

import pytest

from racerlab.cli import main
from tests.exchange.conftest import make_model

pytest.importorskip("tensorboard")  # --car's model.pb protos (racerlab[export])


@pytest.fixture
def model(tmp_path):
    return make_model(tmp_path / "cam4")


def _model_files(folder) -> dict[str, bytes]:
    return {str(p.relative_to(folder.path)): p.read_bytes() for p in sorted(folder.path.rglob("*")) if p.is_file()}


def _refused(args, capsys) -> str:
    assert main(["export", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("racerlab: error: "), err
    return err[0]


@pytest.mark.parametrize("name", ["reward_function.py", "model_metadata.json", "hyperparameters.json",
                                  "training.toml"])
def test_a_file_of_the_model_folder_is_refused_even_with_force(model, tmp_path, capsys, name):
    """Issue 45, item 1: `-o cam4/model_metadata.json` turned the metadata into a gzip (the model no longer evaluated);
    `-o cam4/reward_function.py` replaced the reward with the archive."""
    before = _model_files(model)
    for force in ([], ["--force"]):
        line = _refused([str(model.path), "--car", "-o", str(model.path / name), *force], capsys)
        assert f"that is {name} of the model" in line and "outside it" in line
    assert _model_files(model) == before


def test_a_link_to_a_model_file_is_refused_too(model, tmp_path, capsys):
    (tmp_path / "out.tar.gz").symlink_to(model.path / "reward_function.py")
    before = _model_files(model)
    line = _refused([str(model.path), "--car", "-o", str(tmp_path / "out.tar.gz"), "--force"], capsys)
    assert "reward_function.py of the model" in line and _model_files(model) == before


def test_an_existing_file_it_did_not_write_needs_force(model, tmp_path, capsys):
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    line = _refused([str(model.path), "--car", "-o", str(notes)], capsys)
    assert "did not write it" in line and "--force" in line and notes.read_text() == "my notes\n"
    assert main(["export", str(model.path), "--car", "-o", str(notes), "--force"]) == 0
    with tarfile.open(notes) as tar:
        assert sorted(tar.getnames()) == ["agent/model.pb", "model_metadata.json"]


def test_its_own_archive_is_replaced_without_force(model, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["export", str(model.path), "--car"]) == 0
    out = tmp_path / "cam4-car.tar.gz"
    first = out.stat().st_mtime_ns
    with gzip.open(out) as f:  # the gzip header names the export; tar and the car's upload ignore that name
        assert f.read(1)
    assert main(["export", str(model.path), "--car"]) == 0 and out.stat().st_mtime_ns >= first
    assert "wrote cam4-car.tar.gz" in capsys.readouterr().out


def test_a_folder_gets_the_archive_under_its_default_name(model, tmp_path, capsys):
    (tmp_path / "dist").mkdir()
    assert main(["export", str(model.path), "--car", "-o", str(tmp_path / "dist")]) == 0
    assert (tmp_path / "dist" / "cam4-car.tar.gz").is_file()
    line = _refused([str(model.path), "--car", "-o", str(tmp_path / "new") + os.sep], capsys)
    assert "the folder" in line and "does not exist" in line and not (tmp_path / "new").exists()


@pytest.mark.parametrize("make, words", [
    (lambda tmp: "", "-o '': no file name; give e.g. -o cam4-car.tar.gz"),
    (lambda tmp: "/dev/null", "-o /dev/null: not a regular file (a device)"),
    (lambda tmp: (os.mkfifo(tmp / "pipe"), str(tmp / "pipe"))[1], "not a regular file (a pipe (FIFO))"),
    (lambda tmp: str(tmp / "no" / "such" / "x.tar.gz"), "does not exist; create it"),
], ids=["empty", "device", "fifo", "missing-folder"])
def test_an_output_that_cannot_be_an_archive_is_one_line(model, tmp_path, capsys, make, words):
    """Issue 45, item 1: a device node was replaced without a word; `-o adir` and `-o ''` ended in tracebacks."""
    out = make(tmp_path)
    line = _refused([str(model.path), "--car", "-o", out, "--force"], capsys)
    assert words in line, line
    assert not (tmp_path / "cam4-car.tar.gz").exists()


def test_drfc_into_a_file_is_one_line(model, tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    line = _refused([str(model.path), "--drfc", str(tmp_path / "afile")], capsys)
    assert "not a folder" in line and (tmp_path / "afile").read_text() == "x"
