"""What a training rollout hands the learner at each kind of episode end (issue 17: the finish line)."""

from __future__ import annotations

import numpy as np
import pytest

from racerlab.model import ContinuousActions, ModelMetadata
from racerlab.sim import World
from racerlab.sim.pursuit import PurePursuit
from racerlab.train.rollout import Collector
from tests.conftest import aws_track_path

META = ModelMetadata(ContinuousActions(-30.0, 30.0, 0.5, 4.0), ("FEATURES",), "MLP")


class Driver:
    """An `explore` for one car: pure pursuit of the centre line at 2 m/s, or straight on at 1 m/s."""

    def __init__(self, world, follow: bool):
        self.sim, self.follow = world.sim, follow
        self.pp = PurePursuit.on_centre_line(world.sim.track, speed=2.0)

    def explore(self, obs):
        steer, v = self.pp(self.sim) if self.follow else (np.zeros(1), np.ones(1))
        actions = np.stack([steer / 30.0, (v - 0.5) / 1.75 - 1.0], axis=1).astype(np.float32)
        return actions, {"values": np.zeros(len(actions), np.float32)}


@pytest.fixture()
def world():
    track = str(aws_track_path("reInvent2019_track"))
    return World(track, 1, META, None, "features", max_episode_steps=100_000, seed=0)


def test_a_completed_lap_is_a_truncation_with_the_observation_after_the_finish(world):
    ro = Collector([world]).collect(Driver(world, follow=True), target_episodes=2, max_steps=100_000)
    assert [e.status for e in ro.episodes] == ["lap_complete", "lap_complete"]
    ends = np.flatnonzero(ro.truncated)
    assert len(ends) == 2 and ends[1] == len(ro.rewards) - 1 and not ro.terminated.any()
    assert ends[0] + 1 == ro.episodes[0].steps - 1  # the lap's learning steps (its first, "prepare", is not one)
    n0 = ends[0] + 1
    # the learner bootstraps from V(final_obs): one observation per lap, the car past the line at speed
    assert ro.final_obs.shape == (2, ro.obs.shape[1])
    assert not np.allclose(ro.final_obs[0], ro.obs[n0 - 1])  # the step after the last one, not a copy of it
    assert 0.3 < ro.final_obs[0, 0] < 0.7  # speed / 4 m/s while following at 2 m/s
    assert abs(ro.final_obs[0, 2]) < 0.5  # and near the centre line (lateral offset / half width)


def test_leaving_the_track_stays_a_termination(world):
    ro = Collector([world]).collect(Driver(world, follow=False), target_episodes=1, max_steps=100_000)
    assert [e.status for e in ro.episodes] == ["off_track"]
    assert ro.terminated.tolist() == [False] * (len(ro.rewards) - 1) + [True]
    assert not ro.truncated.any() and ro.final_obs is None
