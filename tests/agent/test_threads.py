"""Torch threads for the learner: convolutional networks get the cores the load average leaves free."""

from torch import nn

from racerlab.agent.common import learner_threads

CONV = [nn.Sequential(nn.Conv2d(1, 4, 3), nn.ReLU(), nn.Flatten(), nn.Linear(4, 2))]
DENSE = [nn.Sequential(nn.Linear(6, 4), nn.ReLU(), nn.Linear(4, 2))]


def test_convolutions_use_the_cores_the_load_leaves_free(monkeypatch):
    monkeypatch.setattr("os.cpu_count", lambda: 8)
    assert learner_threads(CONV, load=0.2) == 8  # idle: every core
    assert learner_threads(CONV, load=1.0) == 8  # this process alone
    assert learner_threads(CONV, load=3.5) == 5  # 2.5 cores busy elsewhere: 5 are free
    assert learner_threads(CONV, load=20.0) == 1  # overloaded: never below 1
    assert learner_threads(CONV, requested=3, load=20.0) == 3  # run.threads wins
    assert learner_threads(DENSE, load=0.2) == 1


def test_the_load_defaults_to_the_one_minute_average(monkeypatch):
    monkeypatch.setattr("os.cpu_count", lambda: 2)
    monkeypatch.setattr("os.getloadavg", lambda: (4.5, 3.0, 2.0), raising=False)
    assert learner_threads(CONV) == 1
    monkeypatch.setattr("os.getloadavg", lambda: (0.9, 3.0, 2.0), raising=False)
    assert learner_threads(CONV) == 2


def test_the_torch_update_sets_its_thread_count_again_each_time():
    # numba's OpenMP launch (the simulator, the renderer) resets the thread count torch shares with it
    import numpy as np
    import torch

    from racerlab.agent.ppo import PPO, PPOBatch
    from racerlab.model.init import make_metadata

    ppo = PPO({"camera": (40, 60, 1)}, make_metadata("camera"), device="cpu", seed=0)
    ppo.threads = 1
    n = 16
    rng = np.random.default_rng(0)
    batch = PPOBatch({"camera": rng.integers(0, 256, (n, 40, 60, 1), dtype=np.uint8)},
                     rng.integers(0, 5, n), np.full(n, -np.log(5), np.float32), np.zeros(n, np.float32),
                     rng.normal(size=n).astype(np.float32), rng.normal(size=n).astype(np.float32))
    seen, real = [], ppo._minibatch_losses

    def counting(*args):
        seen.append(torch.get_num_threads())
        return real(*args)

    ppo._minibatch_losses = counting
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)  # as numba's launch leaves it
        ppo.update(batch)
        assert seen and set(seen) == {1}  # every step ran on the count asked for
        assert torch.get_num_threads() == 2  # and the caller's count is given back
    finally:
        torch.set_num_threads(before)
