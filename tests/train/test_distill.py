"""A camera model from a features teacher (racerlab.train.distill): the paired observation, who drives and what
label each step gets, the rounds end to end, and the camera model staying a plain camera model afterwards."""

from __future__ import annotations

import json

import numpy as np
import pytest

from racerlab.agent import make_agent
from racerlab.agent.imitate import Imitation, teacher_targets
from racerlab.errors import ConfigError
from racerlab.logs import read_metrics_jsonl
from racerlab.model import ModelFolder, init_model, nonfinite_tensors
from racerlab.model.config import parse_training_config
from racerlab.model.init import make_metadata
from racerlab.sim import World
from racerlab.sim.observations import FeaturesObservation
from racerlab.train import train
from racerlab.train.distill import TEACHER_KEY, DaggerDriver, PairedObservation, Teacher
from tests.train.conftest import TRACK, camera_student


@pytest.fixture(scope="module")
def camera_world():
    meta = make_metadata("camera", "continuous", max_speed=4.0)
    world = World(TRACK, 3, meta, None, "camera", seed=3)
    world.step(np.array([[0.5, 1.0], [-0.5, 0.0], [0.0, -1.0]]))  # three different poses
    world.step(np.array([[0.5, 1.0], [-0.5, 0.0], [0.0, -1.0]]))
    return world, meta


def test_the_paired_observation_is_the_frames_and_the_features_of_the_same_cars(camera_world):
    world, _ = camera_world
    own = world.observation
    pair = PairedObservation(own, world.sim, "camera")
    out = pair()
    assert set(out) == {"camera", TEACHER_KEY} and pair.space == own.space
    np.testing.assert_array_equal(out["camera"], own())
    np.testing.assert_array_equal(out[TEACHER_KEY], FeaturesObservation(world.sim)())
    assert len({out[TEACHER_KEY][i].tobytes() for i in range(3)}) == 3  # each car its own vector
    # the rows of a partial update are the same cars' rows of the full observation
    part = pair(np.array([1]))
    np.testing.assert_array_equal(part["camera"][1], out["camera"][1])
    np.testing.assert_array_equal(part[TEACHER_KEY][1], out[TEACHER_KEY][1])


def _driver(world, meta):
    features = FeaturesObservation(world.sim)
    teacher = Teacher(meta.actions)
    teacher.metadata = make_metadata("features", "continuous", max_speed=4.0)
    teacher.agent = make_agent(features.space, teacher.metadata, device="cpu", seed=1)
    student = make_agent(world.observation.space, meta, device="cpu", seed=2)
    imitation = Imitation(student, precision="float32")
    driver = DaggerDriver(imitation, teacher, noise=0.0, seed=0)
    obs = PairedObservation(world.observation, world.sim, "camera")()
    return driver, teacher, imitation, obs


def test_the_driver_labels_every_step_with_the_teacher_and_mixes_who_drives(camera_world):
    world, meta = camera_world
    driver, teacher, imitation, obs = _driver(world, meta)
    expected = teacher_targets(teacher.agent.policy(obs[TEACHER_KEY]), teacher.metadata.actions, meta.actions)
    assert expected.shape == (3, 2) and np.abs(expected).max() <= 1.0
    driver.mix = 1.0  # round 0: the teacher drives every step
    actions, record = driver.explore(obs)
    np.testing.assert_allclose(actions, expected)
    np.testing.assert_allclose(record["target"], expected)
    driver.mix = 0.0  # the student drives (greedy, no noise); the label is still the teacher's
    actions, record = driver.explore(obs)
    np.testing.assert_allclose(actions, imitation.greedy(obs), atol=1e-6)
    np.testing.assert_allclose(record["target"], expected)
    assert not np.allclose(actions, expected)


def test_rounds_fit_the_student_and_leave_a_plain_camera_model(tmp_path, trained_teacher):
    from racerlab.evaluate.api import make_policy

    model = camera_student(tmp_path / "cam")
    teacher_checkpoints = [c.name for c in trained_teacher.checkpoints()]
    r = train(model.path, teacher=trained_teacher.path, iterations=2, progress=False, num_cars=2)
    assert r.iterations == 2
    rows = read_metrics_jsonl(model.path / "metrics" / "metrics.jsonl")
    assert [row["distill/round"] for row in rows] == [0.0, 1.0]
    assert [row["distill/teacher_mix"] for row in rows] == [1.0, 0.5]  # mix 0.5: round k is 0.5 ** k
    # every learning step of both rounds is in the set, and the fit ran passes x new steps / batch rows
    assert rows[1]["distill/set"] == rows[1]["train_steps"]
    assert rows[0]["distill/steps"] == np.ceil(4.0 * rows[0]["train_steps"] / 256)
    assert all(np.isfinite(row["distill/loss_end"]) for row in rows)  # that the fit learns: tests/agent/test_imitate
    # a teacher given for the run is used as it is
    assert [c.name for c in trained_teacher.checkpoints()] == teacher_checkpoints
    # a plain camera model: evaluation loads its checkpoint, and training on without a teacher is PPO from there
    world = World(TRACK, 2, model.metadata(), None, "camera", seed=0)
    assert make_policy(model.open(), world)(world.observe()).shape == (2, 2)
    again = train(model.path, iterations=1, progress=False, num_cars=2)
    assert again.iterations == 3 and "losses/entropy" in again.history[-1]


def test_a_camera_student_whose_fit_turns_nan_rolls_back_as_a_features_model_does(tmp_path, trained_teacher,
                                                                                    monkeypatch):
    """The DAgger rounds skipped the NaN guard, the collapse checks and the rollback (issue 41); the features
    model's case is tests/train/test_trust.py::test_a_non_finite_loss_is_rolled_back_recorded_and_said."""
    model = camera_student(tmp_path / "cam")
    real_fit, rates = Imitation.fit, []

    def once_poisoned(self, inputs, targets, steps, deadline=None):
        metrics = real_fit(self, inputs, targets, steps, deadline=deadline)
        rates.append(self.optimizer.param_groups[0]["lr"])
        if len(rates) == 1:
            next(self.policy.parameters()).data.fill_(float("inf"))
            metrics["distill/loss_end"] = float("nan")
        return metrics

    monkeypatch.setattr(Imitation, "fit", once_poisoned)
    r = train(model.path, teacher=trained_teacher.path, iterations=1, progress=False, num_cars=2)
    assert rates == [0.0005, 0.00025]  # the second try runs with the lowered rate: teacher.lr's
    said = [n for n in r.notes if "rolled back" in n]
    assert r.iterations == 1 and len(said) == 1 and "0.0005 → 0.00025" in said[0]
    assert "lower teacher.lr in training.toml" in said[0]
    entry = read_metrics_jsonl(model.path / "metrics" / "metrics.jsonl")[-1]
    assert entry["rollbacks"] == 1 and "rolled back" in entry["events"][0] and entry["distill/round"] == 0.0
    assert not nonfinite_tensors(model.load_state(model.resolve_checkpoint("last")).agent)


def test_init_camera_trains_its_own_teacher_inside_the_folder(tmp_path):
    model = init_model(tmp_path / "cam", track=TRACK, sensor="camera", max_speed=4.0, action_space="continuous",
                       num_cars=2)
    model.write_hyperparameters(model.hyperparameters().replace(num_episodes_between_training=4))
    cfg = model.config()
    assert cfg.teacher.model == "teacher"
    model.config_path.write_text(model.config_path.read_text().replace("iterations = 30", "iterations = 2"))
    r = train(model.path, iterations=1, progress=False)
    assert r.iterations == 1 and any("phase teacher" in n for n in r.notes)
    teacher = ModelFolder(model.path / "teacher")
    assert teacher.metadata().sensor == ("FEATURES",) and teacher.metadata().actions == model.metadata().actions
    assert teacher.reward_path.read_text() == model.reward_path.read_text() and teacher.checkpoints()
    # the teacher's seconds are kept with the student's checkpoint, so a resumed run does not train it again
    saved = model.load_state(model.resolve_checkpoint("last")).collection
    assert 0 < saved["teacher_seconds"] < 30 and teacher.checkpoints()[-1].iteration == 2
    assert init_model(tmp_path / "plain", sensor="camera", teacher=False).config().teacher.model == ""
    assert init_model(tmp_path / "f", sensor="features").config().teacher.model == ""


@pytest.mark.parametrize(("table", "message"), [
    ({"mix": 2.0}, "teacher.mix = 2.0 is outside its plausible range 0..1"),
    ({"precision": "half"}, "teacher.precision is 'half'"),
    ({"batch_size": 512, "max_steps": 100}, "teacher.max_steps at least teacher.batch_size"),
    # issue 45: an OverflowError traceback, a 17.5 TiB allocation, fits that never end
    ({"minutes": float("inf")}, "teacher.minutes = inf is outside its plausible range 0..1440"),
    ({"minutes": float("nan")}, "teacher.minutes = nan is outside"),
    ({"max_steps": 1_000_000_000}, "teacher.max_steps = 1000000000 is outside its plausible range 1..1000000"),
    ({"passes": 1e9}, "teacher.passes = 1000000000.0 is outside its plausible range 0.001..100"),
    ({"batch_size": 10**9, "max_steps": 10**6}, "teacher.batch_size = 1000000000 is outside"),
    ({"iterations": 10**9}, "teacher.iterations = 1000000000 is outside its plausible range 0..10000"),
    ({"lr": 1e6}, "teacher.lr = 1000000.0 is outside"),
    ({"noise": float("inf")}, "teacher.noise = inf is outside"),
])
def test_bad_teacher_settings_name_the_key_and_its_range(table, message):
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")) as err:
        parse_training_config({"teacher": table}, "x/training.toml")
    assert str(err.value).startswith("x/training.toml: ") and "\n" not in str(err.value)


def test_a_teacher_that_is_not_a_features_model_is_refused(tmp_path):
    cam = init_model(tmp_path / "cam", track=TRACK, sensor="camera", teacher=False)
    other = init_model(tmp_path / "other", track=TRACK, sensor="camera", teacher=False)
    with pytest.raises(ConfigError, match="a teacher must be a features PPO model"):
        train(cam.path, teacher=other.path, iterations=1, progress=False, num_cars=2)
    assert json.loads(cam.metadata_path.read_text())["sensor"] == ["FRONT_FACING_CAMERA"]
