"""Small helpers PPO and SAC share: device choice, seeded construction, numpy observations to tensors."""

from __future__ import annotations

import contextlib
import math
import os
import time
from collections.abc import Iterator, Mapping

import numpy as np
import torch

# An observation batch as the simulator gives it: one array with the batch axis first, or a dict of them
# for combined sensors ({"camera": (B,120,160,1) uint8, "lidar": (B,64) float32}).
Obs = np.ndarray | Mapping[str, np.ndarray]


def resolve_device(device: str | torch.device = "auto") -> torch.device:
    """"auto" is CUDA when PyTorch sees a GPU, else CPU; anything else is passed to `torch.device`."""
    if isinstance(device, str) and device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


@contextlib.contextmanager
def seeded(seed: int) -> Iterator[None]:
    """Seed PyTorch's CPU generator for a block (network initialisation) and restore it afterwards."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        yield


def learner_threads(networks, requested: int = 0, load: float | None = None) -> int:
    """Torch CPU threads for training `networks`: `requested` when > 0; else 1 for dense networks on vectors,
    whose small products gain nothing from a second thread and lose much when the machine is busy, and
    for a network with convolutions the cores nobody else is using: every core less the 1-minute load
    average beyond this process's own one (`load`, default `os.getloadavg()`), at least 1.

    An OpenMP parallel region waits for its slowest thread, so a thread sharing its core with another
    busy process holds up all of them: on a 2-core machine at load 4.5 a camera PPO gradient step took
    1.06 s with 2 threads and 0.27 s with 1 (docs/learner.md, "Camera update on CPU")."""
    if requested > 0:
        return int(requested)
    if not any(isinstance(m, torch.nn.Conv2d) for net in networks for m in net.modules()):
        return 1
    cores = os.cpu_count() or 1
    if load is None:
        load = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
    return max(1, min(cores, math.floor(cores + 1.0 - load)))


def make_generator(seed: int, device: torch.device) -> torch.Generator:
    return torch.Generator(device=device).manual_seed(seed)


def to_tensors(obs: Obs, keys: tuple[str, ...], device: torch.device) -> dict[str, torch.Tensor]:
    """numpy observations -> {input name: tensor on device}, dtypes kept (uint8 images stay uint8)."""
    if isinstance(obs, Mapping):
        missing = [k for k in keys if k not in obs]
        if missing:
            raise KeyError(f"observation lacks input(s) {missing}; the network takes {list(keys)}")
        return {k: torch.as_tensor(obs[k], device=device) for k in keys}
    if len(keys) != 1:
        raise TypeError(f"the network takes a dict of inputs {list(keys)}, got one array")
    return {keys[0]: torch.as_tensor(obs, device=device)}


def batch_size_of(obs: Mapping[str, torch.Tensor]) -> int:
    return next(iter(obs.values())).shape[0]


def take(obs: Obs, idx) -> Obs:
    """Rows `idx` of an observation batch (an array or a dict of arrays)."""
    if isinstance(obs, dict):
        return {k: v[idx] for k, v in obs.items()}
    return obs[idx]


def generator_state(gen: torch.Generator) -> dict:
    return {"device": gen.device.type, "state": gen.get_state()}


def restore_generator(gen: torch.Generator, saved: dict | None) -> None:
    """Restore a generator saved on the same kind of device; a CPU/GPU switch keeps the fresh one."""
    if saved is not None and saved.get("device") == gen.device.type:
        gen.set_state(saved["state"].cpu())


class ThreadChooser:
    """Picks, again and again while an update runs, the faster of `threads` and 1 torch threads.

    On a machine whose other cores are busy, each parallel region of a convolution waits for its slowest
    thread, and a thread that shares its core with another process is slow: a SHALLOW camera step took
    500-700 ms with 2 threads and 170 ms with 1 at load 3-4 on 2 cores, and 85 ms with 2 against 150 ms
    with 1 when a core was free. Which is faster changes within minutes, so at the start of each period
    one step runs on 1 thread and one on `threads`, and the rest of the period uses the faster. The very
    first step (oneDNN creates its kernels then) runs on `threads` before the first period. A period is `every` steps,
    doubled (up to 8x) while the loser takes over twice as long, since each trial of it costs a slow step.
    Results do not depend on the choice beyond float rounding.
    """

    def __init__(self, threads: int, every: int = 40):
        self.threads, self.base = int(threads), int(every)
        self.every = self.base
        self.chosen = self.threads
        self.step = 0  # steps taken
        self._start = 1  # the step the current period began at
        self._times: dict[int, float] = {}
        self._current = self.threads
        self._t0 = 0.0

    def __enter__(self) -> int:
        if self.threads <= 1:
            return self.threads
        p = self.step - self._start
        n = (1, self.threads)[p] if 0 <= p < 2 else self.chosen
        if n != torch.get_num_threads():
            torch.set_num_threads(n)
        self._current = n
        self._t0 = time.perf_counter()
        return n

    def __exit__(self, *exc) -> None:
        if self.threads <= 1:
            return
        p = self.step - self._start
        if 0 <= p < 2:
            self._times[self._current] = time.perf_counter() - self._t0
        if p == 1:
            fast, slow = sorted(self._times, key=self._times.get)
            self.chosen = fast
            lopsided = self._times[slow] > 2.0 * self._times[fast]
            self.every = min(self.every * 2, 8 * self.base) if lopsided else self.base
        self.step += 1
        if self.step - self._start >= self.every:
            self._start, self._times = self.step, {}

    def restore(self) -> None:
        """Back to `threads` (acting and evaluation keep the configured count)."""
        if torch.get_num_threads() != self.threads:
            torch.set_num_threads(self.threads)
