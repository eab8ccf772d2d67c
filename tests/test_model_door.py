"""Every reader of a trained model opens it through one door, `ModelFolder.open`: evaluation, both kinds of race,
the held-out tracks, every export format, S3 push, clone, import's check, the console and the command line. Each
path below is watched at the door (it must knock with the model's folder) and handed a checkpoint with a NaN
weight, which each must refuse with the door's one line, writing nothing.

The two readers inside `racerlab.train` (resume and the camera model's teacher) are in
`test_train_readers_open_through_the_door`.
"""

from __future__ import annotations

import re
import time

import pytest
import torch

from racerlab.errors import ModelRefused
from racerlab.model import ModelFolder
from tests.exchange.conftest import make_model


@pytest.fixture
def door(monkeypatch):
    """The folders `ModelFolder.open` was called on, in order."""
    knocked, real = [], ModelFolder.open

    def watched(self, checkpoint="best"):
        knocked.append(self.path.resolve())
        return real(self, checkpoint)

    monkeypatch.setattr(ModelFolder, "open", watched)
    return knocked


def poison(folder: ModelFolder) -> str:
    """Put a NaN into the first policy weight of the folder's newest checkpoint; the line the door refuses it with,
    worked out here from the file's name and the tensor's."""
    info = folder.checkpoints()[-1]
    raw = folder.load_checkpoint(info)
    name = next(iter(raw["agent"]["policy"]))
    raw["agent"]["policy"][name].view(-1)[0] = float("nan")
    torch.save(raw, folder.checkpoint_path(info))
    older = [c.iteration for c in folder.checkpoints()[:-1]]
    hint = f"pick an older one with --checkpoint {older[-1]}" if older else "train it again"
    return f"{folder.checkpoint_path(info)}: non-finite weights (policy.{name}); the training diverged there: {hint}"


@pytest.fixture
def nan_model(tmp_path):
    """A camera model (the kind every export takes) whose only checkpoint holds a NaN, and the refusal's line."""
    folder = make_model(tmp_path / "cam", "camera")
    return folder, poison(folder)


def _readers(tmp_path):
    """name -> a call that reads the model at `path` (each as its users call it)."""
    from racerlab.evaluate import evaluate, head_to_model, race
    from racerlab.evaluate.generalise import evaluate_tracks
    from racerlab.exchange import export_car, export_drfc, export_droa, export_onnx, export_tflite
    from racerlab.exchange.s3 import push
    from racerlab.model import clone_model

    return {
        "evaluate": lambda p: evaluate(p, trials=1, write=False),
        "race": lambda p: race([p], out=False),
        "head to model": lambda p: head_to_model(p, p, write=False, out=False),
        "held-out tracks": lambda p: evaluate_tracks(p, ["lab_oval"]),
        "export car": lambda p: export_car(p, tmp_path / "out-car.tar.gz"),
        "export onnx": lambda p: export_onnx(p, tmp_path / "out-onnx.tar.gz"),
        "export tflite": lambda p: export_tflite(p, tmp_path / "out-tflite.tar.gz"),
        "export droa": lambda p: export_droa(p, tmp_path / "out-droa.tar.gz"),
        "export drfc": lambda p: export_drfc(p, tmp_path / "out-drfc"),
        "s3 push": lambda p: push(p, "s3://no-bucket/prefix", progress=lambda *a: None),
        "clone": lambda p: clone_model(p, tmp_path / "out-clone"),
    }


READERS = ["evaluate", "race", "head to model", "held-out tracks", "export car", "export onnx", "export tflite",
           "export droa", "export drfc", "s3 push", "clone"]


@pytest.mark.parametrize("reader", READERS)
def test_every_reader_refuses_a_nan_checkpoint_at_the_door_with_its_line(tmp_path, nan_model, door, reader):
    folder, line = nan_model
    with pytest.raises(ModelRefused) as err:
        _readers(tmp_path)[reader](folder.path)
    assert str(err.value) == line and err.value.reason == ModelRefused.NONFINITE
    assert door and set(door) == {folder.path.resolve()}
    assert not [p for p in tmp_path.iterdir() if p.name.startswith("out-")]  # nothing written
    assert not list(folder.path.glob("evaluation-*"))


def test_import_opens_the_folder_it_wrote_through_the_door(tmp_path, door):
    from racerlab.exchange import export_car, import_model

    folder = make_model(tmp_path / "cam", "camera")
    archive = export_car(folder.path, tmp_path / "cam-car.tar.gz")
    door.clear()
    out = import_model(archive, tmp_path / "back")
    assert len(door) == 1 and door[0].name == "model"  # the staged folder, checked before it takes its name
    assert ModelFolder(out).open().checkpoint.iteration == 0


def _task_end(client, key: str, timeout: float = 120) -> dict:
    deadline = time.monotonic() + timeout
    while (task := client.get(f"/api/tasks/{key}").json())["status"] == "running":
        assert time.monotonic() < deadline, f"task {key} still running after {timeout} s"
        time.sleep(0.2)
    return task


def test_the_console_refuses_a_nan_checkpoint_with_the_doors_line(tmp_path, door):
    from tests.console.conftest import Console

    console = Console(tmp_path / "ws")
    try:
        c, root = console.client, console.app.state.workspace.root
        folder = make_model(root / "cam", "camera")
        line = poison(folder)
        for key, route in (("export:cam:car", "/api/models/cam/export/car"),
                           ("export:cam:droa", "/api/models/cam/export/droa"),
                           ("evaluate:cam", "/api/models/cam/evaluate")):
            assert c.post(route).json()["status"] == "running"
            task = _task_end(c, key)
            assert (task["status"], task["message"]) == ("failed", line), key
        assert c.get("/api/models/cam/exports").json()["exports"] == []
        assert c.get("/api/models/cam/evaluations").json()["evaluations"] == []
        assert door == [folder.path.resolve()] * 3
    finally:
        console.stop()


def test_the_command_line_refuses_a_nan_checkpoint_with_one_line_for_every_command(tmp_path, nan_model, capsys):
    from racerlab.cli import main

    folder, line = nan_model
    said = {}
    for name, argv in (("export --car", ["export", str(folder.path), "--car", "-o", str(tmp_path / "c.tar.gz")]),
                       ("export --onnx", ["export", str(folder.path), "--onnx", "-o", str(tmp_path / "o.tar.gz")]),
                       ("export --droa", ["export", str(folder.path), "--droa", "-o", str(tmp_path / "d.tar.gz")]),
                       ("evaluate", ["evaluate", str(folder.path), "--trials", "1"])):
        assert main(argv) == 2, name
        out = capsys.readouterr()
        said[name] = out.err
        assert out.out == "", name
    assert set(said.values()) == {f"racerlab: error: {line}\n"}, said
    assert not list(tmp_path.glob("*.tar.gz")) and not list(folder.path.glob("evaluation-*"))


# ---- the readers inside racerlab.train (converted on the trainer's branch) ---------------------------------------


def test_train_readers_open_through_the_door(tmp_path, door):
    from racerlab.model import init_model
    from racerlab.sim.core import Simulator
    from racerlab.sim.observations import FeaturesObservation
    from racerlab.track import load
    from racerlab.train import train
    from racerlab.train.distill import load_teacher

    # resume: the newest checkpoint refused at the door is skipped for the one before it, and the note says why
    model = _small(init_model(tmp_path / "m", track="lab_oval", sensor="features"))
    train(model.path, iterations=2, progress=False, num_cars=2)
    newest = model.checkpoint_path(model.checkpoints()[-1])
    poison(model)
    door.clear()
    r = train(model.path, iterations=1, progress=False, num_cars=2)
    assert any(n.startswith(f"skipping {newest}: non-finite weights (policy.") for n in r.notes), r.notes
    assert r.iterations == 2  # resumed from iteration 1 and trained one more
    assert door and set(door) == {model.path.resolve()}
    # the teacher: a features teacher whose best checkpoint holds a NaN is refused with the door's line
    teacher = _small(init_model(tmp_path / "t", track="lab_oval", sensor="features"))
    train(teacher.path, iterations=1, progress=False, num_cars=2)
    line = poison(teacher)
    teacher.update_index(teacher.checkpoints()[-1], 0.0, teacher.checkpoints()[-1], 0.0)
    door.clear()
    space = FeaturesObservation(Simulator(load("lab_oval"), 1)).space
    with pytest.raises(ModelRefused) as err:
        load_teacher(teacher.path, space)
    assert str(err.value) == line and door == [teacher.path.resolve()]


def _small(folder: ModelFolder) -> ModelFolder:
    """Short iterations: 2 episodes of at most 150 steps."""
    folder.write_hyperparameters(folder.hyperparameters().replace(num_episodes_between_training=2))
    text = folder.config_path.read_text()
    folder.config_path.write_text(re.sub(r"(?m)^max_episode_steps = .*$", "max_episode_steps = 150", text))
    return folder
