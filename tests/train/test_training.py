"""Training end to end on a real track: learning, checkpoints, resume, clone, NaN guard, errors, logs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from racerlab.errors import ConfigError, RewardFunctionError
from racerlab.model import ModelFolder, clone_model, init_model
from racerlab.train import TrainingDiverged, train
from tests.conftest import aws_track_path

FAST = dict(progress=False, num_cars=16)


@pytest.fixture
def model(tmp_path):
    track = str(aws_track_path("reInvent2019_track"))
    folder = init_model(tmp_path / "model", track=track, max_speed=2.0)
    return folder


def test_short_training_raises_progress(model):
    # 9 iterations: the AWS car (issue 24: its delay, hinge lag, weak steering and jittered steps) takes a few more
    # than the old instant car's 6 to learn the first corners (a run: completion 7.5 % -> 70.6 %, a 10.3 s lap)
    r = train(model.path, iterations=9, **FAST)
    completion = [h["charts/completion"] for h in r.history]
    assert r.iterations == 9
    assert np.mean(completion[-2:]) > completion[0] + 20
    assert r.first_lap is not None and r.best_lap_time < 25


def test_checkpoints_logs_and_round_trip(model):
    from racerlab.agent import make_agent
    from racerlab.logs import read_metrics_jsonl

    r = train(model.path, iterations=6, **FAST)
    f = ModelFolder(model.path)
    names = [c.name for c in f.checkpoints()]
    index = json.loads(f.checkpoints_json.read_text())
    assert index["last_checkpoint"]["name"] == names[-1] and names[-1].startswith("6_Step-")
    assert len(names) <= 5 and index["best_checkpoint"]["name"] in names  # last 4 + best
    assert (f.checkpoints_dir / ".coach_checkpoint").read_text().strip() == names[-1]
    # logs: one simtrace per iteration, an AWS metrics entry per episode, one metrics line per iteration
    assert sorted(p.name for p in (model.path / "training-simtrace").iterdir()) == \
        [f"{i}-iteration.csv" for i in range(6)]
    doc = json.loads((model.path / "metrics" / "TrainingMetrics.json").read_text())
    train_eps = [m for m in doc["metrics"] if m["phase"] == "training"]
    assert len(train_eps) == r.episodes and doc["version"] == 2.0
    assert [m["iteration"] for m in read_metrics_jsonl(model.path / "metrics" / "metrics.jsonl")] == list(range(1, 7))
    # a checkpoint round trip gives identical actions
    ck = f.load_state(f.resolve_checkpoint("last"))
    obs = np.random.default_rng(0).normal(size=(32, 20)).astype(np.float32)
    meta, hp = f.metadata(), f.hyperparameters()
    import gymnasium as gym

    space = gym.spaces.Box(-10, 10, (20,), np.float32)
    a, b = make_agent(space, meta, hp, device="cpu", seed=1), make_agent(space, meta, hp, device="cpu", seed=2)
    a.load_state_dict(ck.agent)
    b.load_state_dict(ck.agent)
    assert np.array_equal(a.act(obs, greedy=True)[0], b.act(obs, greedy=True)[0])
    assert np.allclose(a.act(obs, greedy=True)[2], b.act(obs, greedy=True)[2])


def test_deepracer_utils_reads_the_model_folder(model):
    deepracer = pytest.importorskip("deepracer.logs", reason="deepracer-utils is a test dependency")
    r = train(model.path, iterations=2, **FAST)
    log = deepracer.DeepRacerLog(str(model.path))
    log.load_training_trace()
    df = log.dataframe()
    rows = sum(len(p.read_text().splitlines()) - 1 for p in (model.path / "training-simtrace").iterdir())
    assert len(df) == rows and df["episode"].nunique() == r.episodes
    assert len(log.action_space()) == 10  # from the model/model_metadata.json copy


def test_resume_after_kill_9(model):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen([sys.executable, "-m", "racerlab", "train", str(model.path), "--iterations", "500",
                             "--cars", "16"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    f = ModelFolder(model.path)
    deadline = time.time() + 120
    while time.time() < deadline and (not f.checkpoints() or f.checkpoints()[-1].iteration < 3):
        assert proc.poll() is None, proc.stderr.read().decode()
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    last = f.resolve_checkpoint("last")  # the newest complete file, even if the kill beat the index update
    assert last.iteration >= 3
    r = train(model.path, iterations=1, **FAST)
    assert r.iterations == last.iteration + 1
    doc = json.loads((model.path / "metrics" / "TrainingMetrics.json").read_text())
    episodes = [m["episode"] for m in doc["metrics"] if m["phase"] == "training"]
    assert episodes == list(range(1, r.episodes + 1))  # nothing lost, nothing counted twice
    simtraces = sorted(p.name for p in (model.path / "training-simtrace").iterdir() if not p.name.startswith("."))
    assert simtraces == [f"{i}-iteration.csv" for i in range(r.iterations)]


def test_reward_that_raises_stops_with_file_line_and_keeps_the_model(model):
    train(model.path, iterations=1, **FAST)
    model.reward_path.write_text(textwrap.dedent("""
        def reward_function(params):
            if params["progress"] > 5:
                raise ValueError("boom")
            return 1.0
    """))
    with pytest.raises(RewardFunctionError) as err:
        train(model.path, iterations=3, **FAST)
    assert f"{model.reward_path}:4" in str(err.value) and "ValueError: boom" in str(err.value)
    assert ModelFolder(model.path).resolve_checkpoint("last").iteration == 1


def test_clone_refused_when_shapes_differ(model, tmp_path):
    train(model.path, iterations=1, **FAST)
    other = tmp_path / "meta.json"
    meta = json.loads(model.metadata_path.read_text())
    meta["action_space"] = meta["action_space"][:3]
    other.write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match=r"number of actions 10 → 3"):
        clone_model(model.path, tmp_path / "child", model_metadata=other)
    assert not (tmp_path / "child").exists()


def test_clone_continues_from_parent(model, tmp_path):
    train(model.path, iterations=2, **FAST)
    meta = json.loads(model.metadata_path.read_text())
    for a in meta["action_space"]:
        a["speed"] *= 1.5  # action values may change
    new_meta = tmp_path / "faster.json"
    new_meta.write_text(json.dumps(meta))
    child = clone_model(model.path, tmp_path / "child", checkpoint="last", model_metadata=new_meta)
    lineage = json.loads(child.lineage_path.read_text())
    assert lineage["checkpoint"].startswith("2_Step-") and lineage["changed"] == ["model_metadata.json"]
    r = train(child.path, iterations=1, **FAST)
    assert r.iterations == 3  # numbering continues from the parent's checkpoint


def test_nan_guard_rolls_back_then_stops(model, monkeypatch):
    from racerlab.agent.ppo import PPO

    train(model.path, iterations=1, **FAST)
    lrs = []
    real_update = PPO.update

    def poisoned(self, batch):
        lrs.append(self.lr)
        real_update(self, batch)
        for p in self.policy_net.parameters():
            p.data.fill_(float("nan"))
        return {"losses/policy": float("nan"), "nonfinite": 1.0}

    monkeypatch.setattr(PPO, "update", poisoned)
    with pytest.raises(TrainingDiverged, match="3 rollbacks"):
        train(model.path, iterations=5, **FAST)
    assert lrs == [0.0003, 0.00015, 0.000075]
    f = ModelFolder(model.path)
    assert f.resolve_checkpoint("last").iteration == 1  # nothing non-finite reached a checkpoint
    assert f.load_state(f.resolve_checkpoint("last")).agent["policy"] is not None


def test_multi_track_spreads_cars(model):
    from racerlab.train.loop import Trainer

    t = Trainer(model.path, progress=False, num_cars=5,
                tracks=[str(aws_track_path("reInvent2019_track")), str(aws_track_path("reinvent_base"))])
    assert [w.sim.num_cars for w in t.collector.worlds] == [3, 2]
    assert t.collector.worlds[1].sim.track.name == "reinvent_base"


@pytest.mark.parametrize("algorithm", ["clipped_ppo", "sac"])
def test_truncated_episodes_and_sac(tmp_path, algorithm):
    """Episodes cut by the step cap are kept apart from terminations; SAC trains from the same rollouts."""
    track = str(aws_track_path("reInvent2019_track"))
    folder = init_model(tmp_path / "m", track=track, algorithm=algorithm, action_space="continuous", num_cars=4)
    text = folder.config_path.read_text().replace("max_episode_steps = 10000", "max_episode_steps = 20")
    folder.config_path.write_text(text)
    r = train(folder.path, iterations=2, progress=False)
    assert r.iterations == 2
    doc = json.loads((folder.path / "metrics" / "TrainingMetrics.json").read_text())
    statuses = {m["episode_status"] for m in doc["metrics"] if m["phase"] == "training"}
    assert "Time Up" in statuses  # the cap truncated episodes (AWS's label for a time limit)
    assert ModelFolder(folder.path).resolve_checkpoint("last").iteration == 2
