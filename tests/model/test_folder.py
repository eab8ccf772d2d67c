"""ModelFolder: which tracks a model uses, its files, and a training.toml that accepts registered observations."""

from __future__ import annotations

import pytest

from racerlab import track as tracks
from racerlab.errors import ConfigError, TrackError
from racerlab.model import ModelFolder, TrainingState, init_model, load_training_config, resolve_track
from racerlab.model.metadata import OBSERVATION_NAMES


def _write_tracks(folder: ModelFolder, names: list[str]) -> None:
    quoted = ", ".join(f'"{n}"' for n in names)
    folder.config_path.write_text(f"[track]\nnames = [{quoted}]\n[run]\nnum_cars = 4\n")


def test_tracks_come_from_training_toml_in_order(tmp_path):
    folder = init_model(tmp_path / "m")
    _write_tracks(folder, ["lab_oval", "lab_technical"])
    assert folder.tracks() == ("lab_oval", "lab_technical")
    assert resolve_track(folder).name == "lab_oval"  # the first one
    assert resolve_track(folder.path).name == "lab_oval"  # a path works as well as a ModelFolder


def test_a_given_track_wins_over_the_model_folder(tmp_path):
    folder = init_model(tmp_path / "m", track="lab_oval")
    assert resolve_track(folder, "lab_technical").name == "lab_technical"
    given = tracks.load("lab_technical")
    assert resolve_track(folder, given) is given


def test_without_training_toml_the_model_trains_on_the_default_track(tmp_path):
    folder = init_model(tmp_path / "m")
    folder.config_path.unlink()
    # `racerlab train` uses TrainingConfig's default track when training.toml is absent ...
    assert folder.tracks() == load_training_config(folder.config_path).track.names == ("lab_technical",)
    assert resolve_track(folder).name == "lab_technical"
    # ... but a folder without training.toml (a log folder, an AWS download) names no track of its own
    assert folder.tracks(default=False) == ()
    assert resolve_track(folder, default=False) is None
    assert resolve_track(tmp_path / "no-such-folder", default=False) is None


def test_a_bad_training_toml_or_track_is_a_one_line_error(tmp_path):
    folder = init_model(tmp_path / "m")
    folder.config_path.write_text("[track]\nnames = 3\n")
    with pytest.raises(ConfigError, match="track.names must be a non-empty list of strings"):
        folder.tracks()
    _write_tracks(folder, ["no_such_track_anywhere"])
    with pytest.raises(TrackError, match="no_such_track_anywhere"):
        resolve_track(folder)


def test_model_files_and_checkpoint_paths(tmp_path):
    folder = init_model(tmp_path / "m")
    assert [p.name for p in folder.model_files] == ["reward_function.py", "model_metadata.json",
                                                    "hyperparameters.json", "training.toml"]
    assert all(p.is_file() and p.parent == folder.path for p in folder.model_files)
    info = folder.save_state(TrainingState({"x": 1}, iteration=3, train_steps=120, best_name="2_Step-80.pt",
                                           collection={"starts": [4, 5]}))
    assert folder.checkpoint_path(info) == folder.checkpoints_dir / "3_Step-120.pt"
    assert folder.checkpoint_path(info).is_file()
    back = folder.load_state(info)
    assert back.agent == {"x": 1} and (back.iteration, back.train_steps, back.best_name) == (3, 120, "2_Step-80.pt")
    assert back.collection == {"starts": [4, 5]} and not back.cloned
    raw = folder.load_checkpoint(info)  # the file's keys, as racerlab has always written them
    assert raw["format"] == "racerlab.checkpoint/1" and raw["starts"] == [4, 5] and "cloned" not in raw
    folder.write_reward("def reward_function(params):\n    return 2.0 * params['speed']\n")
    assert folder.reward_function()({"speed": 1.5}) == 3.0
    assert folder.write_file("imported/a.txt", b"x").read_bytes() == b"x"
    for outside in ("../a.txt", "/tmp/a.txt"):
        with pytest.raises(ValueError, match="not a path inside"):
            folder.write_file(outside, b"x")
    assert not list(folder.path.rglob("*.tmp-*"))  # the atomic writes left no temporary file behind


def test_a_registered_observation_is_accepted_by_training_toml(tmp_path):
    from racerlab.sim.observations import OBSERVATIONS, FeaturesObservation, register_observation

    p = tmp_path / "training.toml"
    p.write_text('[run]\nobservation = "features_test_copy"\n')
    with pytest.raises(ConfigError, match="run.observation must be empty"):
        load_training_config(p)
    register_observation("features_test_copy", FeaturesObservation)
    try:
        assert load_training_config(p).run.observation == "features_test_copy"
    finally:
        OBSERVATIONS.pop("features_test_copy")
        OBSERVATION_NAMES.remove("features_test_copy")
