"""Submissions are data: hostile or broken uploads are refused in one line, nothing from them runs, and an AWS
export of a model is the same model as its racerlab folder."""

from __future__ import annotations

import io
import os
import tarfile

import pytest

from racerlab.league import LeagueError
from racerlab.league.convert import convert_upload, read_converted
from tests.league.conftest import features_model

MARKER = "league-pickle-ran"


class Payload:
    """What a hostile checkpoint holds: unpickling it would create a file."""

    def __init__(self, path):
        self.path = path

    def __reduce__(self):
        return (open, (self.path, "w"))


def _with_checkpoint(folder, data: bytes) -> None:
    (folder.path / "checkpoints" / "1_Step-100.pt").write_bytes(data)


def test_a_pickle_payload_in_place_of_a_checkpoint_is_refused_and_never_runs(tmp_path, straight):
    import torch

    folder = features_model(tmp_path / "m", straight)
    marker = tmp_path / MARKER
    buf = io.BytesIO()
    torch.save({"agent": {"policy": Payload(str(marker))}, "format": "racerlab.checkpoint/1"}, buf)
    _with_checkpoint(folder, buf.getvalue())
    with pytest.raises(LeagueError, match="refused: the checkpoint holds more than racerlab writes") as err:
        convert_upload(folder.path, tmp_path / "work")
    assert not marker.exists() and "\n" not in str(err.value)
    assert str(tmp_path / "work") not in str(err.value)  # the server's folders are not in the answer


def test_nan_weights_are_refused(tmp_path, straight):
    from racerlab.model import ModelFolder

    folder = features_model(tmp_path / "m", straight)
    state = folder.load_state(folder.resolve_checkpoint("best"))
    next(iter(state.agent["policy"].values())).view(-1)[0] = float("nan")
    ModelFolder(folder.path).save_state(state)
    with pytest.raises(LeagueError, match="non-finite weights"):
        convert_upload(folder.path, tmp_path / "work")


def test_a_checkpoint_of_another_model_is_refused(tmp_path, straight):
    import json

    folder = features_model(tmp_path / "m", straight)
    meta = json.loads(folder.metadata_path.read_text())
    meta["action_space"].append({"steering_angle": 30.0, "speed": 1.0, "index": 1})
    folder.metadata_path.write_text(json.dumps(meta))
    with pytest.raises(LeagueError, match="does not match .*model_metadata.json"):
        convert_upload(folder.path, tmp_path / "work")


def test_links_and_escaping_members_are_refused(tmp_path, straight):
    folder = features_model(tmp_path / "m", straight)
    os.symlink("/etc/passwd", folder.path / "hyperparameters.json")
    with pytest.raises(LeagueError, match="a symbolic link"):
        convert_upload(folder.path, tmp_path / "work1")
    archive = tmp_path / "evil.tar.gz"
    with tarfile.open(archive, "w:gz") as tar:
        data = b"{}"
        info = tarfile.TarInfo("../../model_metadata.json")
        info.size = len(data)
        tar.addfile(info, io.BytesIO(data))
    with pytest.raises(LeagueError, match="outside the model folder"):
        convert_upload(archive, tmp_path / "work2")


def test_the_child_is_held_to_its_memory_and_its_deadline(tmp_path, straight):
    from tests.exchange.conftest import make_model

    camera = make_model(tmp_path / "cam", "camera", "discrete")  # a 70 MB checkpoint: more than the 16 MB allowed
    with pytest.raises(LeagueError, match="needed more than 0.015625 GiB of memory"):
        convert_upload(camera.path, tmp_path / "work1", memory_bytes=16 << 20)
    folder = features_model(tmp_path / "m", straight)
    with pytest.raises(LeagueError, match="longer than 0.001 s"):
        convert_upload(folder.path, tmp_path / "work2", deadline_s=0.001)


def test_not_a_model_is_one_line(tmp_path):
    junk = tmp_path / "junk.tar.gz"
    junk.write_bytes(b"not an archive at all")
    with pytest.raises(LeagueError, match="not a readable .tar.gz or .zip"):
        convert_upload(junk, tmp_path / "work")
    (tmp_path / "empty").mkdir()
    with pytest.raises(LeagueError, match="no model_metadata.json"):
        convert_upload(tmp_path / "empty", tmp_path / "work2")


def test_the_cars_archive_of_a_model_is_that_model(tmp_path):
    pytest.importorskip("tensorboard", reason="the car's graph protos come with tensorboard")
    from racerlab.exchange import export_car
    from tests.exchange.conftest import make_model

    model = make_model(tmp_path / "cam", "camera", "discrete")
    archive = export_car(model.path, tmp_path / "cam-car.tar.gz")
    folder = convert_upload(model.path, tmp_path / "w1")
    car = convert_upload(archive, tmp_path / "w2")
    assert (folder.source, car.source) == ("racerlab", "aws-pb")
    assert car.model_hash == folder.model_hash  # the same policy, metadata and observation: one model
    assert read_converted(car.folder, "x").sensor == ("FRONT_FACING_CAMERA",)
