"""`Trainer` collects and logs through what it is given: any object with the collection's methods and any
logs writer (the cluster passes its Ray collection and per-worker logs this way, without subclassing)."""

from __future__ import annotations

import re

from racerlab.model import init_model
from racerlab.reward import RewardCaller
from racerlab.train import LocalCollection, Trainer, TrainingLogs, WorldBuilder, apply_overrides
from tests.conftest import aws_track_path


class CountingCollection:
    """This machine's worlds, counting what the trainer asks of them and keeping one extra state key."""

    def __init__(self, inner: LocalCollection):
        self.inner = inner
        self.calls: list[tuple] = []
        self.closed = False

    def before_iteration(self, iteration):
        self.calls.append(("before", iteration))

    def collect(self, agent, target, max_steps, first_episode_number=0, *, deadline=None, tick=None):
        self.calls.append(("collect", target, first_episode_number))
        return self.inner.collect(agent, target, max_steps, first_episode_number, deadline=deadline, tick=tick)

    def state(self):
        return {"starts": [len(self.calls)]}

    def restore(self, saved):
        self.calls.append(("restore", saved))

    def metrics(self, iteration):
        return {"test/collects": sum(c[0] == "collect" for c in self.calls)}

    def close(self):
        self.closed = True


class KeptLogs:
    """A logs writer that keeps the metrics lines and writes the AWS logs through `TrainingLogs`."""

    def __init__(self, inner: TrainingLogs):
        self.inner = inner
        self.lines: list[dict] = []
        self.iterations: list[int] = []

    def write_iteration(self, iteration, ro, evals, first_episode):
        self.iterations.append(iteration)
        self.inner.write_iteration(iteration, ro, evals, first_episode)

    def append_metrics(self, entry):
        self.lines.append(entry)

    def truncate(self, iteration, episodes):
        self.inner.truncate(iteration, episodes)

    def disk_bytes(self):
        return self.inner.disk_bytes()

    def close(self):
        self.inner.close()


def _pieces(folder, **overrides):
    cfg = apply_overrides(folder.config(), **overrides)
    builder = WorldBuilder(cfg, folder.metadata(), RewardCaller(folder.reward_function()))
    return CountingCollection(LocalCollection(builder)), KeptLogs(TrainingLogs(folder.path, cfg))


def test_a_trainer_collects_and_logs_through_what_it_is_given(tmp_path):
    folder = init_model(tmp_path / "m", track=str(aws_track_path("reInvent2019_track")), max_speed=2.0)
    hp = folder.hyperparameters_path.read_text()
    folder.hyperparameters_path.write_text(re.sub(r'"num_episodes_between_training": \d+',
                                                  '"num_episodes_between_training": 2', hp))
    folder.config_path.write_text(re.sub(r"(?m)^max_episode_steps = .*$", "max_episode_steps = 150",
                                         folder.config_path.read_text()))
    collection, logs = _pieces(folder, num_cars=2)
    r = Trainer(folder.path, progress=False, collector=collection, logs=logs, num_cars=2, iterations=2).run()
    assert r.iterations == 2 and collection.closed
    assert [c for c in collection.calls if c[0] != "collect"] == [("before", 0), ("before", 1)]
    assert [c[1:] for c in collection.calls if c[0] == "collect"] == [(2, 0), (2, r.history[0]["episodes"])]
    assert logs.iterations == [1, 2] and [e["iteration"] for e in logs.lines] == [1, 2]
    assert [e["test/collects"] for e in logs.lines] == [1, 2]  # the collection's own metrics join each line
    assert folder.load_state(folder.resolve_checkpoint("last")).collection == {"starts": [4]}
    # a resumed run hands the collection what it kept
    collection, logs = _pieces(folder, num_cars=2)
    Trainer(folder.path, progress=False, collector=collection, logs=logs, num_cars=2, iterations=1).run()
    assert collection.calls[0] == ("restore", {"starts": [4]})
