"""The supervised half of DAgger: the teacher's actions as the student's labels, the data set's cap, the fit."""

import gymnasium as gym
import numpy as np
import pytest
import torch

from racerlab.agent import PPO
from racerlab.agent.imitate import Demonstrations, Imitation, precision_dtype, teacher_targets
from racerlab.errors import ConfigError
from racerlab.model.metadata import ContinuousActions, DiscreteActions, ModelMetadata

WIDE = ContinuousActions(-30.0, 30.0, 0.5, 4.0)  # the benchmark's action space (init --max-speed 4)


def test_same_continuous_space_keeps_the_teacher_action_clipped_to_the_box():
    a = np.array([[0.5, -0.2], [1.5, -3.0]])
    np.testing.assert_allclose(teacher_targets(a, WIDE, WIDE), [[0.5, -0.2], [1.0, -1.0]], atol=1e-6)


def test_other_continuous_ranges_map_through_the_commands():
    # teacher [0.5, 0]: steering 15°, speed 0.5 + 0.5 * 3.5 = 2.25 m/s; the student's ranges are ±15° and
    # [1, 4] m/s: steering 15° is its +1, and 2.25 m/s is 2 * (1.25 / 3) - 1 = -1/6
    narrow = ContinuousActions(-15.0, 15.0, 1.0, 4.0)
    out = teacher_targets(np.array([[0.5, 0.0], [-1.0, -1.0]]), WIDE, narrow)
    # teacher [-1, -1]: -30° and 0.5 m/s, beyond the student's -15° and 1 m/s: its corner [-1, -1]
    np.testing.assert_allclose(out, [[1.0, -1.0 / 6.0], [-1.0, -1.0]], atol=1e-6)
    assert out.dtype == np.float32


def test_a_discrete_student_gets_the_nearest_action():
    student = DiscreteActions((-30.0, 0.0, 30.0, 0.0), (1.0, 1.0, 1.0, 2.0))  # top speed 2 m/s
    teacher = ContinuousActions(-30.0, 30.0, 0.0, 2.0)
    # [0, 0.9] → 0°, 1.9 m/s: to (0°, 2) (0.1/2)² = 0.0025, to (0°, 1) (0.9/2)² = 0.2025 → index 3
    # [2/3, 0] → 20°, 1 m/s: to (30°, 1) (10/30)² = 0.111, to (0°, 1) (20/30)² = 0.444 → index 2
    out = teacher_targets(np.array([[0.0, 0.9], [2.0 / 3.0, 0.0]]), teacher, student)
    assert out.tolist() == [3, 2] and out.dtype == np.int64
    # the same list on both sides gives every index back
    assert teacher_targets(np.arange(4), student, student).tolist() == [0, 1, 2, 3]


def test_demonstrations_keep_every_new_step_and_replace_old_ones_past_the_cap():
    d = Demonstrations(capacity=4, seed=0)
    d.add({"x": np.array([1, 2, 3])})
    assert len(d) == 3 and d.column("x").tolist() == [1, 2, 3]
    d.add({"x": np.array([10, 20, 30])})
    kept = d.column("x").tolist()
    # one free row took 10; 20 and 30 replaced two of the old steps 1, 2, 3
    assert len(d) == 4 and d.seen == 6 and kept[3] == 10
    assert {20, 30} <= set(kept) and len({1, 2, 3} & set(kept)) == 1
    with pytest.raises(ValueError, match="columns"):
        d.add({"y": np.array([1])})
    with pytest.raises(ConfigError, match="capacity"):
        Demonstrations(capacity=0)


def _camera_student(discrete=False):
    actions = DiscreteActions((-30.0, 30.0), (1.0, 1.0)) if discrete else WIDE
    meta = ModelMetadata(actions, ("FRONT_FACING_CAMERA",), "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW")
    # a small image the AWS 3-layer network still fits (40 → 9 → 3 → 1)
    return PPO(gym.spaces.Box(0, 255, (40, 40, 1), np.uint8), meta, device="cpu", seed=0)


def _two_pictures(n=64):
    frames = np.zeros((n, 40, 40, 1), np.uint8)
    frames[n // 2:] = 255  # half black, half white
    return frames


def test_the_fit_teaches_the_plain_policy_network_the_targets():
    agent = _camera_student()
    frames = _two_pictures()
    targets = np.zeros((64, 2), np.float32)
    targets[:32] = [0.5, -0.5]  # black: steer left-ish, slow; white: the opposite
    targets[32:] = [-0.5, 0.5]
    imitation = Imitation(agent, batch_size=32, lr=1e-3, precision="float32", threads=1)
    m = imitation.fit({"camera": frames}, targets, steps=150)
    assert m["distill/steps"] == 150 and m["distill/loss_end"] < 0.01 < m["distill/loss_start"]
    # the model's own greedy action (what evaluation and export use) is what the student learnt
    np.testing.assert_allclose(agent.policy(frames[[0, -1]]), [[0.5, -0.5], [-0.5, 0.5]], atol=0.1)
    np.testing.assert_allclose(imitation.greedy(frames[[0, -1]]), agent.policy(frames[[0, -1]]), atol=1e-5)


def test_a_discrete_student_learns_the_teacher_indices():
    agent = _camera_student(discrete=True)
    frames = _two_pictures()
    targets = np.repeat(np.array([1, 0], np.int64), 32)  # black → action 1, white → action 0
    Imitation(agent, batch_size=32, lr=1e-3, precision="float32", threads=1).fit({"camera": frames}, targets, 80)
    assert agent.policy(frames[[0, -1]]).tolist() == [1, 0]


def test_precision_names():
    assert precision_dtype("float32", torch.device("cpu")) is None
    assert precision_dtype("bfloat16", torch.device("cpu")) is torch.bfloat16
    assert precision_dtype("auto", torch.device("cuda")) is torch.bfloat16
    with pytest.raises(ConfigError, match="teacher.precision"):
        precision_dtype("half", torch.device("cpu"))
