"""The generalist recipe's bookkeeping: `init --preset generalise --tracks-from DIR` trains on every layout of DIR
but the held-out ones, a camera model drives its tracks a few at a time, and its teacher drives them all."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from racerlab.errors import ConfigError, RacerlabError
from racerlab.model import ModelFolder, TrainingConfig, init_model
from racerlab.model.config import TrackSettings, parse_training_config
from racerlab.model.init import GENERALIST_CAMERA, training_set
from racerlab.track.core import from_array
from racerlab.track.layouts import held_out_tracks, layout_shape, same_layout
from tests.track.test_layouts import circle, ring, tee


@pytest.fixture
def folder(tmp_path):
    """Five layouts in eight files: A (a, a_cw, b moved elsewhere, c mirrored), circles d, e and f of 3, 4 and 5 m,
    and g, a tee half as large again (another layout)."""
    files = {"a": tee(), "a_cw": tee()[::-1], "b": tee() + [30.0, 0.0], "c": tee() * [-1.0, 1.0],
             "d": circle(3.0), "e": circle(4.0, 20, 20), "f": circle(5.0, -20, 0), "g": tee(1.5)}
    out = tmp_path / "tracks"
    out.mkdir()
    for name, pts in files.items():
        np.save(out / f"{name}.npy", ring(pts))
    return out


def _shape(name_or_path):
    return layout_shape(from_array(np.load(str(name_or_path)), "t"))


def _held_out(folder_path: ModelFolder) -> list[str]:
    first = folder_path.config_path.read_text().splitlines()[0]
    assert first.startswith("# training set: ")
    return first.split("): ", 1)[1].split(", ")


@pytest.mark.parametrize("seed", range(4))
def test_no_held_out_layout_is_ever_trained_on(tmp_path, folder, seed):
    m = init_model(tmp_path / "m", sensor="camera", action_space="continuous", preset="generalise",
                   tracks_from=folder, held_out=2, held_out_seed=seed)
    names, held = m.config().track.names, _held_out(m)
    assert len(held) == 2 and len(names) == 3  # 5 layouts: 2 held out, one file of each of the other 3 trained on
    for h in held:
        assert not any(same_layout(_shape(folder / f"{h}.npy"), _shape(n)) for n in names), (seed, h)
    assert not any(same_layout(_shape(x), _shape(y)) for i, x in enumerate(names) for y in names[i + 1:])
    # drawn again from the tracks the model never saw, any held-out set is those 2 layouts (a file of each)
    for again in range(3):
        drawn = held_out_tracks(folder, 2, exclude=names, seed=again)
        assert all(sum(same_layout(_shape(p), _shape(folder / f"{h}.npy")) for p in drawn) == 1 for h in held)
    with pytest.raises(RacerlabError, match="2 closed track layouts not excluded, fewer than the 3 asked"):
        held_out_tracks(folder, 3, exclude=names)


def test_the_evaluation_track_is_trained_on_first_and_never_held_out(folder):
    for seed in range(5):
        tset = training_set(folder, 4, seed, track=str(folder / "c.npy"))
        assert tset.names == (str((folder / "c.npy").resolve()),)  # a, b and c's layout: c alone, first
        assert sorted(tset.held_out) == ["d", "e", "f", "g"]
    with pytest.raises(RacerlabError, match="all its 5 closed layouts held out, none left to train on"):
        training_set(folder, 5)
    with pytest.raises(RacerlabError, match="5 closed track layouts not excluded, fewer than the 6 asked"):
        training_set(folder, 6)


def test_a_camera_generalist_gets_the_recipe(tmp_path, folder):
    m = init_model(tmp_path / "m", sensor="camera", action_space="continuous", max_speed=4.0, preset="generalise",
                   tracks_from=folder, held_out=1)
    cfg = m.config()
    assert m.reward_path.read_text().startswith('"""Reward template "pace"')
    assert cfg.teacher.model == "teacher" and cfg.teacher.minutes == GENERALIST_CAMERA["teacher"]["minutes"]
    assert cfg.track.generated == 0 and cfg.track.at_once == 14 and cfg.run.num_cars == 28
    assert m.hyperparameters().num_episodes_between_training == 28  # one episode per car in each round
    r = cfg.randomise
    assert r.lighting and r.latency_varies and r.latency_steps == 1 and r.camera_noise == 4.0 and r.pose_yaw_deg == 2
    assert not r.evaluation  # the evaluation after each round drives plain, as before
    feats = init_model(tmp_path / "f", preset="generalise", tracks_from=folder, held_out=1)
    assert not feats.config().randomise.active and len(feats.config().track.names) == 4
    with pytest.raises(RacerlabError, match="--tracks-from .*goes with --preset generalise"):
        init_model(tmp_path / "x", sensor="camera", tracks_from=folder)


def test_named_tracks_are_driven_a_few_at_a_time_in_turn():
    t = TrackSettings(names=("a", "b", "c", "d", "e"), at_once=2)
    assert t.rotates and t.driven == 2
    assert [t.names_of_draw(d) for d in range(4)] == [("a", "b"), ("c", "d"), ("e", "a"), ("b", "c")]
    for whole in (TrackSettings(names=("a", "b"), at_once=2), TrackSettings(names=("a", "b"), at_once=0),
                  TrackSettings(names=("a", "b", "c"), at_once=1, generated=4)):
        assert not whole.rotates and whole.names_of_draw(7) == whole.names
    with pytest.raises(ConfigError, match="track.at_once must be >= 0"):
        parse_training_config({"track": {"at_once": -1}}, "m/training.toml")
    with pytest.raises(ConfigError, match="run.num_cars must be at least the number of tracks driven at once"):
        parse_training_config({"track": {"names": ["a", "b", "c"], "at_once": 2}, "run": {"num_cars": 1}},
                              "m/training.toml")
    parse_training_config({"track": {"names": ["a", "b", "c"], "at_once": 2}, "run": {"num_cars": 2}}, "m/t.toml")


def test_the_collection_drives_the_next_tracks_every_few_iterations(tmp_path):
    from racerlab.train.worlds import LocalCollection, WorldBuilder

    m = init_model(tmp_path / "m")
    cfg = replace(TrainingConfig(), track=TrackSettings(names=("lab_oval", "lab_technical", "lab_grand_prix"),
                                                        at_once=2, regenerate_every=2), )
    cfg = replace(cfg, run=replace(cfg.run, num_cars=4))
    col = LocalCollection(WorldBuilder(cfg, m.metadata(), None))
    seen = []
    for it in range(6):
        col.before_iteration(it)
        seen.append(tuple(w.sim.track.name for w in col.worlds))
        assert [w.sim.num_cars for w in col.worlds] == [2, 2]
    pairs = [("lab_oval", "lab_technical"), ("lab_grand_prix", "lab_oval"), ("lab_technical", "lab_grand_prix")]
    assert seen == [pairs[0], pairs[0], pairs[1], pairs[1], pairs[2], pairs[2]]


def test_the_teacher_drives_every_track_in_every_iteration(tmp_path):
    from racerlab.train.distill import create_teacher

    m = init_model(tmp_path / "m", sensor="camera")
    cfg = m.config()
    cfg = replace(cfg, track=replace(cfg.track, names=("lab_oval",) * 40, at_once=14),
                  run=replace(cfg.run, num_cars=28))
    teacher = create_teacher(m, cfg, tmp_path / "m" / "teacher")
    tcfg = teacher.config()
    assert tcfg.track.at_once == 0 and len(tcfg.track.names) == 40
    assert tcfg.run.num_cars == 40  # one car per track (more than the default 32)
    assert teacher.hyperparameters().num_episodes_between_training == 40  # and an episode for each
    small = create_teacher(m, m.config(), tmp_path / "t2")  # one track: the default 32 cars and 32 episodes
    assert small.config().run.num_cars == 32 and small.hyperparameters().num_episodes_between_training == 32
