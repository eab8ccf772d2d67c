"""Learning a policy from a teacher's actions: the supervised half of DAgger (racerlab.train.distill drives it).

A camera model learns the road from pixels a hundred times more slowly by reinforcement than a `features` model
learns it from its compact vector. So the features model is trained first and becomes the teacher: in every state
the camera student visits, the teacher's greedy action (computed from the features vector of the same car) is the
label, and the student's policy network is fitted to the labels by plain supervised learning.

- `teacher_targets`: the teacher's actions as the student's actions. Both action spaces are read as commands
  (steering °, speed m/s); a continuous student gets them back in its [-1, 1]² (clipped to its ranges), a discrete
  one the nearest of its actions (steering counted in units of 30°, speed in units of the top speed).
- `Demonstrations`: the aggregated data set (the student's observations and the teacher's inputs of the same
  steps), with a cap on its size; past it, new steps replace random old ones.
- `Imitation`: the fit (a continuous policy's mean to the targets by squared error, a discrete policy's logits by
  cross-entropy) and the greedy actions the student drives with while its data is collected. On a CPU with
  bfloat16 units (AMX, AVX512-BF16) and on CUDA both run under bfloat16 autocast (`precision="auto"`): the AWS
  camera network's step is ~2x faster and its inference ~2.4x (docs/learner.md); the weights stay float32.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Mapping

import numpy as np
import torch
import torch.nn.functional as F

from racerlab.agent.common import learner_threads, make_generator, to_tensors
from racerlab.errors import ConfigError
from racerlab.model.config import PRECISIONS
from racerlab.model.metadata import ContinuousActions

STEER_UNIT_DEG = 30.0  # the discrete nearest-action metric: 30° of steering weigh as much as the top speed


def _commands(actions, space) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(space, ContinuousActions):
        return space.rescale(np.asarray(actions, dtype=np.float64).reshape(-1, 2))
    return space.lookup(np.asarray(actions).reshape(-1))


def _normalised(steer, speed, space: ContinuousActions) -> np.ndarray:
    """(steering °, speed) as a continuous space's [-1, 1]² action, clipped to its ranges."""
    def inverse(x, low, high):
        return np.zeros_like(x) if high == low else 2.0 * (x - low) / (high - low) - 1.0

    out = np.stack([inverse(steer, space.steering_low, space.steering_high),
                    inverse(speed, space.speed_low, space.speed_high)], axis=-1)
    return np.clip(out, -1.0, 1.0).astype(np.float32)


def _nearest(steer, speed, space) -> np.ndarray:
    """Index of the discrete action nearest each command."""
    top = max(float(space.top_speed), 1e-9)
    s = np.asarray(space.steering_deg, dtype=np.float64)
    v = np.asarray(space.speed, dtype=np.float64)
    d = ((steer[:, None] - s[None]) / STEER_UNIT_DEG) ** 2 + ((speed[:, None] - v[None]) / top) ** 2
    return d.argmin(axis=1).astype(np.int64)


def teacher_targets(actions, teacher_space, student_space) -> np.ndarray:
    """The student's actions for the teacher's greedy `actions` [B] or [B, 2] (each space a model's `actions`):
    float32 [B, 2] in [-1, 1] for a continuous student, int64 [B] indices for a discrete one."""
    steer, speed = _commands(actions, teacher_space)
    if isinstance(student_space, ContinuousActions):
        return _normalised(steer, speed, student_space)
    return _nearest(steer, speed, student_space)


class Demonstrations:
    """The aggregated data set: the student's inputs (uint8 frames, ...) and the teacher's inputs of the same
    steps, `capacity` steps at most; once full, each new step takes the place of a random old one (DAgger keeps
    every round's data; the cap bounds memory: a 120x160 frame is 19.2 kB, 60 000 of them 1.15 GB)."""

    def __init__(self, capacity: int, seed: int = 0):
        if capacity < 1:
            raise ConfigError(f"the demonstrations' capacity must be at least 1, got {capacity}")
        self.capacity = capacity
        self.size = 0
        self.seen = 0  # steps ever added
        self.columns: dict[str, np.ndarray] = {}
        self.rng = np.random.default_rng(seed)
        self.last_rows = np.empty(0, dtype=np.int64)

    def __len__(self) -> int:
        return self.size

    def add(self, steps: Mapping[str, np.ndarray]) -> int:
        """Add the rows of `steps` ({name: [N, ...]}, the same names every time); returns how many were added."""
        n = len(next(iter(steps.values())))
        if not self.columns:
            self.columns = {k: np.empty((self.capacity, *np.shape(v)[1:]), dtype=np.asarray(v).dtype)
                            for k, v in steps.items()}
        if set(steps) != set(self.columns):
            raise ValueError(f"demonstration steps have columns {sorted(steps)}, the set {sorted(self.columns)}")
        free = min(n, self.capacity - self.size)
        rows = np.arange(self.size, self.size + free)
        if n > free:  # full: the rest replace random old steps (distinct rows, so none overwrites a new one)
            old = self.rng.choice(self.size, size=min(n - free, self.size), replace=False)
            rows = np.concatenate([rows, old])
        for k, v in steps.items():
            self.columns[k][rows] = np.asarray(v)[:len(rows)]
        self.size += free
        self.seen += n
        self.last_rows = rows  # where they went (a store of the set writes those rows: train.dagger_store)
        return len(rows)

    def column(self, name: str) -> np.ndarray:
        return self.columns[name][:self.size]


def precision_dtype(precision: str, device: torch.device) -> torch.dtype | None:
    """The autocast dtype for `precision` on `device`: None (float32) or torch.bfloat16. "auto" takes bfloat16 on
    CUDA and on a CPU with bfloat16 units (AMX or AVX512-BF16), where it is ~2x faster; float32 elsewhere."""
    if precision not in PRECISIONS:
        raise ConfigError(f"teacher.precision is {precision!r}; use one of {', '.join(PRECISIONS)}")
    if precision == "float32":
        return None
    if precision == "bfloat16":
        return torch.bfloat16
    if device.type == "cuda":
        return torch.bfloat16
    cpu = getattr(torch, "cpu", None)
    units = any(getattr(cpu, name, lambda: False)() for name in ("_is_amx_tile_supported", "_is_avx512_bf16_supported"))
    return torch.bfloat16 if units else None


class Imitation:
    """Fits `agent`'s policy network (a `PPO`) to a teacher's targets, and drives greedily while data is collected.

    `batch_size` rows a gradient step, Adam at `lr` (its own optimizer: PPO's stays as it was), `precision` as
    `precision_dtype`. `threads` torch CPU threads for the fit (0: `learner_threads`, which follows the load)."""

    def __init__(self, agent, *, batch_size: int = 256, lr: float = 5e-4, precision: str = "auto", seed: int = 0,
                 threads: int = 0):
        self.agent = agent
        self.policy = agent.policy_net
        self.device = agent.device
        self.keys = agent.keys
        self.discrete = agent.discrete
        self.batch_size = int(batch_size)
        self.dtype = precision_dtype(precision, self.device)
        self.threads = threads
        self.optimizer = torch.optim.Adam(self.policy.parameters(), lr=lr, eps=1e-5)
        self.generator = make_generator(seed, torch.device("cpu"))

    def _autocast(self):
        if self.dtype is None:
            return contextlib.nullcontext()
        return torch.autocast(self.device.type, dtype=self.dtype)

    @torch.inference_mode()
    def greedy(self, obs) -> np.ndarray:
        """The student's greedy actions [B] or [B, 2] (its policy's argmax or mean) for a batch of observations, on 1
        thread or torch's count, whichever is faster now (`PPO._threads`: 8 camera frames took 5x the CPU time on 2
        threads as on 1 on a busy 2-core machine)."""
        threads = getattr(self.agent, "_threads", None)
        with (threads("imitation") if threads else contextlib.nullcontext()), self._autocast():
            out = self.policy(to_tensors(obs, self.keys, self.device)).float()
        return (out.argmax(-1) if self.discrete else out).cpu().numpy()

    def loss(self, obs: dict[str, torch.Tensor], targets: torch.Tensor) -> torch.Tensor:
        with self._autocast():
            out = self.policy(obs)
        out = out.float()
        if self.discrete:
            return F.cross_entropy(out, targets)
        return F.mse_loss(out, targets)

    def fit(self, inputs: Mapping[str, np.ndarray], targets: np.ndarray, steps: int,
            deadline: float | None = None) -> dict[str, float]:
        """`steps` Adam steps on minibatches drawn at random from `inputs` ({key: [N, ...]}, the policy's keys)
        and `targets` [N] or [N, 2]; stops early after the step in progress at `deadline` (`time.perf_counter()`).
        Returns the mean loss of the first and of the last tenth of the steps, and the steps run."""
        n = len(targets)
        if n == 0 or steps < 1:
            return {"distill/loss_start": float("nan"), "distill/loss_end": float("nan"), "distill/steps": 0.0}
        given = torch.get_num_threads()
        if self.device.type == "cpu":
            torch.set_num_threads(learner_threads((self.policy,), self.threads))
        losses = []
        try:
            for _ in range(steps):
                idx = torch.randint(0, n, (min(self.batch_size, n),), generator=self.generator).numpy()
                idx.sort()  # rows in memory order: the gather from the frames is a little faster
                obs = to_tensors({k: inputs[k][idx] for k in self.keys}, self.keys, self.device)
                y = torch.as_tensor(targets[idx], device=self.device)
                loss = self.loss(obs, y)
                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                self.optimizer.step()
                losses.append(loss.detach())
                if deadline is not None and time.perf_counter() >= deadline:
                    break
        finally:
            torch.set_num_threads(given)
        values = torch.stack(losses).cpu().numpy()
        tenth = max(1, len(values) // 10)
        return {"distill/loss_start": float(values[:tenth].mean()), "distill/loss_end": float(values[-tenth:].mean()),
                "distill/steps": float(len(values))}
