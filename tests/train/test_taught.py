"""A taught camera model as a careful user meets it (issue 45): Ctrl-C in the teacher phase stops the whole run, a
resumed run keeps DAgger's data set and the fit's optimiser, the model's own teacher follows the model's reward and
car (a teacher given for the run is said to be used as it is), a clone brings its teacher, and `--teacher DIR` is a
path from the current folder like every other flag's."""

from __future__ import annotations

import copy
import shutil

import torch

from racerlab.agent import make_agent
from racerlab.agent.imitate import Imitation
from racerlab.cli import main
from racerlab.logs import read_metrics_jsonl
from racerlab.model import ModelFolder, TrainingState, clone_model, init_model
from racerlab.sim import World
from racerlab.train import train
from tests.train.conftest import TRACK, camera_student

NEW_REWARD = "def reward_function(params):\n    return float(params['speed'])\n"


def _own_teacher_model(path, iterations: int = 1):
    """A camera model with its own teacher (`racerlab init --sensor camera`), which trains `iterations`."""
    model = init_model(path, track=TRACK, sensor="camera", max_speed=4.0, action_space="continuous", num_cars=2)
    model.write_hyperparameters(model.hyperparameters().replace(num_episodes_between_training=4, num_epochs=1))
    text = model.config_path.read_text()
    assert "\niterations = 30\n" in text  # [teacher] iterations
    model.config_path.write_text(text.replace("\niterations = 30\n", f"\niterations = {iterations}\n"))
    return model


def _rows(model):
    return read_metrics_jsonl(model.path / "metrics" / "metrics.jsonl")


def test_ctrl_c_while_the_teacher_trains_stops_the_whole_run(tmp_path, monkeypatch):
    """On bfddeb1 the run went on into DAgger for ~70 s and exited 0, so `train && evaluate` ran on."""
    from racerlab.train.loop import Trainer

    model = _own_teacher_model(tmp_path / "cam", iterations=3)
    real = Trainer.iterate

    def iterate(self, t_start):
        if self.folder.path == model.path / "teacher" and self.state.iteration >= 1:
            raise KeyboardInterrupt  # Ctrl-C in the teacher's second iteration
        return real(self, t_start)

    monkeypatch.setattr(Trainer, "iterate", iterate)
    assert main(["train", str(model.path), "--iterations", "2"]) == 130
    assert [c.iteration for c in model.checkpoints()] == [0]  # no DAgger round
    metrics = model.path / "metrics" / "metrics.jsonl"
    assert not metrics.exists() or read_metrics_jsonl(metrics) == []
    assert [c.iteration for c in ModelFolder(model.path / "teacher").checkpoints()][-1] == 1  # its iteration is kept


def _fit_states(monkeypatch) -> list[tuple[dict, dict]]:
    """The fit's optimiser before and after each fit."""
    seen, real = [], Imitation.fit

    def fit(self, inputs, targets, steps, deadline=None):
        before = copy.deepcopy(self.optimizer.state_dict())
        metrics = real(self, inputs, targets, steps, deadline=deadline)
        seen.append((before, copy.deepcopy(self.optimizer.state_dict())))
        return metrics

    monkeypatch.setattr(Imitation, "fit", fit)
    return seen


def test_a_resumed_taught_run_keeps_its_data_set_and_the_fits_optimiser(tmp_path, trained_teacher, monkeypatch):
    model = camera_student(tmp_path / "cam")
    fits = _fit_states(monkeypatch)
    train(model.path, teacher=trained_teacher.path, iterations=1, progress=False, num_cars=2)
    kept = fits[-1][1]
    round0 = _rows(model)[-1]
    assert round0["distill/set"] == round0["train_steps"] > 0  # round 0: the teacher's own driving, labelled
    model.reward_path.write_text(NEW_REWARD)  # the teacher given for the run keeps its own, and the run says so
    r = train(model.path, teacher=trained_teacher.path, iterations=1, progress=False, num_cars=2)
    round1 = _rows(model)[-1]
    # bfddeb1 started the set empty: round 1's steps alone
    assert round1["distill/round"] == 1.0 and round1["distill/set"] == round1["train_steps"] > round0["train_steps"]
    assert any(n.startswith(f"dagger: resumed with {round0['train_steps']:.0f} labelled steps") for n in r.notes)
    found = fits[-1][0]  # the resumed run's fit starts from the optimiser the first run ended with
    assert found["param_groups"][0]["lr"] == kept["param_groups"][0]["lr"]
    assert sorted(found["state"]) == sorted(kept["state"]) and len(kept["state"]) > 0
    for i, st in kept["state"].items():
        for key, value in st.items():
            assert torch.equal(found["state"][i][key], value), (i, key)
    apart = [n for n in r.notes if "is used as it is" in n]
    assert len(apart) == 1 and "its own reward_function.py" in apart[0] and "[car]" not in apart[0]


def test_the_models_own_teacher_follows_its_reward_and_car(tmp_path):
    """On bfddeb1 the teacher kept the reward and car copied when it was created."""
    model = _own_teacher_model(tmp_path / "cam")
    train(model.path, iterations=1, progress=False)
    teacher = ModelFolder(model.path / "teacher")
    assert teacher.checkpoints()[-1].iteration == 1  # its budget of 1 iteration is spent
    model.reward_path.write_text(NEW_REWARD)
    text = model.config_path.read_text()  # a car constant, as `racerlab calibrate --out` merges it
    model.config_path.write_text(text.replace('[car]\nsimulator = "droa"\n', '[car]\nsimulator = "droa"\n'
                                                                                'speed_tau_s = 0.2\n'))
    r = train(model.path, iterations=1, progress=False)
    assert teacher.reward_path.read_text() == NEW_REWARD
    assert teacher.config().car == model.config().car and dict(model.config().car.overrides) == {"speed_tau_s": 0.2}
    assert teacher.checkpoints()[-1].iteration == 2  # trained again, for the new reward and car
    said = [n for n in r.notes if "takes the model's" in n]
    assert len(said) == 1 and "reward_function.py and [car]" in said[0]
    again = train(model.path, iterations=1, progress=False)  # nothing changed since: no more teacher training
    assert teacher.checkpoints()[-1].iteration == 2 and not any("takes the model's" in n for n in again.notes)


def test_a_clone_of_a_taught_model_brings_its_teacher(tmp_path, trained_teacher):
    """On bfddeb1 the clone copied `[teacher]` but not `teacher/`, so it trained a new teacher."""
    source = init_model(tmp_path / "cam", track=TRACK, sensor="camera")
    assert source.config().teacher.model == "teacher"
    shutil.copytree(trained_teacher.path, source.path / "teacher")
    (source.path / "teacher" / "training.lock").write_text("12345\n")  # a lock is the source's run's, not the clone's
    world = World(TRACK, 1, source.metadata(), None, "camera", seed=0)
    agent = make_agent(world.observation.space, source.metadata(), device="cpu", seed=0)
    source.save_state(TrainingState(agent=agent.state_dict(), metadata=source.metadata().to_json(), iteration=3,
                                    train_steps=30))
    copy_ = clone_model(source.path, tmp_path / "copy")
    teacher = ModelFolder(copy_.path / "teacher")
    assert [c.name for c in teacher.checkpoints()] == [c.name for c in trained_teacher.checkpoints()]
    assert teacher.reward_path.read_text() == trained_teacher.reward_path.read_text()
    assert not (teacher.path / "training.lock").exists()


def test_the_teacher_flag_is_a_path_from_the_current_folder(tmp_path, trained_teacher, monkeypatch, capsys):
    """On bfddeb1 `--teacher DIR` was looked for inside the model folder, and the fix it suggested made a features
    model there."""
    monkeypatch.chdir(trained_teacher.path.parent)
    model = camera_student(tmp_path / "cam")
    assert main(["train", str(model.path), "--teacher", trained_teacher.path.name, "--iterations", "1",
                 "--cars", "2"]) == 0
    assert [row["distill/round"] for row in _rows(model)] == [0.0]
    capsys.readouterr()
    assert main(["train", str(model.path), "--teacher", "nowhere", "--iterations", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("racerlab: error: --teacher nowhere: nowhere is not a model folder") and "\n" not in err
    assert "`racerlab init nowhere --sensor features` and `racerlab train nowhere --minutes 2`" in err
    assert str(model.path) not in err
    untrained = init_model(trained_teacher.path.parent / "untrained", track=TRACK)
    assert main(["train", str(model.path), "--teacher", untrained.path.name, "--iterations", "1"]) == 2
    assert "`racerlab train untrained --minutes 2`" in capsys.readouterr().err
    assert [c.iteration for c in model.checkpoints()] == [0, 1]  # neither error touched the model
