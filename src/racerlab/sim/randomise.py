"""Domain randomisation for the physical car: what a `World` changes between the policy and the simulator.

`training.toml`'s `[randomise]` table (`racerlab.model.config.RandomiseSettings`) names the options; the
two classes here apply them to a batch of cars, drawing from one seeded generator:

- `Actuation` (World.step): the car's speed mapping (speeds relative to the action space's top speed,
  scaled to `top_speed` × `speed_scale`), per-episode steering and throttle gains, and a delay of 0-2
  steps between the action chosen and the action applied;
- `RandomisedObservation` (World.observe): per-episode camera pose (yaw and sideways offset move the
  rendered viewpoint; pitch shifts the image rows), blur, exposure and gamma, per-frame pixel noise, and
  lidar range noise. `lighting` is the camera's own per-episode look (`camera:dr`, set by the World).

A car's episode starts when its step counter is 0: that is when its per-episode values are drawn. With
every option at its default the World builds neither, and the plain path runs unchanged.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import gaussian_filter1d

from racerlab.model.config import RandomiseSettings
from racerlab.sim import _kernels as K

CAMERA_KEYS = ("camera", "stereo")
IMAGE_OPTIONS = ("camera_noise", "blur", "exposure", "gamma", "pose_pitch_deg")
POSE_OPTIONS = ("pose_yaw_deg", "pose_shift_m")
SEED_SALT = 0x5EED_D0  # keeps the randomisation's generator apart from the simulator's for the same seed


def make_rng(seed: int | None) -> np.random.Generator:
    return np.random.default_rng(None if seed is None else [int(seed), SEED_SALT])


def as_settings(randomise) -> RandomiseSettings | None:
    """`RandomiseSettings`, its keyword dict, or None; None when nothing is randomised."""
    if randomise is None:
        return None
    r = randomise if isinstance(randomise, RandomiseSettings) else RandomiseSettings(**randomise)
    return r if r.active else None


def _gains(rng, n: int, spread: float) -> np.ndarray:
    return rng.uniform(1.0 - spread, 1.0 + spread, size=n) if spread else np.ones(n)


class Actuation:
    """Commanded (steering °, speed m/s) → applied, for every car: speed mapping, gains and latency."""

    def __init__(self, settings: RandomiseSettings, num_cars: int, action_top_speed: float, rng):
        self.s = settings
        self.rng = rng
        top = settings.top_speed or action_top_speed
        self.speed_factor = top / action_top_speed * settings.speed_scale
        self.gain = np.ones((num_cars, 2))  # steering, throttle
        self.history = np.zeros((num_cars, settings.latency_steps + 1, 2))  # newest first

    def __call__(self, steer: np.ndarray, speed: np.ndarray, steps: np.ndarray, active=None):
        """Applied (steering, speed) for the cars in `active` (all by default); `steps` is each car's step
        counter before this step (0 = the first step of an episode, AWS's prepare step)."""
        idx = np.arange(steer.size) if active is None else np.flatnonzero(active)
        cmd = np.stack([steer[idx], speed[idx] * self.speed_factor], axis=1)
        fresh = idx[steps[idx] == 0]
        if fresh.size:
            self.gain[fresh, 0] = _gains(self.rng, fresh.size, self.s.steering_gain)
            self.gain[fresh, 1] = _gains(self.rng, fresh.size, self.s.throttle_gain)
            self.history[fresh] = cmd[np.searchsorted(idx, fresh)][:, None, :]
        hist = self.history[idx]
        hist[:, 1:] = hist[:, :-1]
        hist[:, 0] = cmd
        self.history[idx] = hist
        applied = hist[:, -1] * self.gain[idx]
        out_steer, out_speed = steer.copy(), speed.copy()
        out_steer[idx], out_speed[idx] = applied[:, 0], applied[:, 1]
        return out_steer, out_speed


class RandomisedObservation:
    """Wraps an observation and perturbs its camera frames and lidar ranges (see the module docstring)."""

    def __init__(self, inner, sim, settings: RandomiseSettings, rng):
        self.inner = inner
        self.sim = sim
        self.s = settings
        self.rng = rng
        self.name = getattr(inner, "name", None)
        self.partial_update = getattr(inner, "partial_update", False)
        n = sim.num_cars
        self.sigma = np.zeros(n)  # blur, pixels
        self.gain = np.ones(n)  # exposure
        self.gamma = np.ones(n)
        self.row_shift = np.zeros(n, dtype=np.int64)  # pitch, image rows (+ = the scene moves up)
        self.cameras = [p.camera for p in _parts(inner) if hasattr(p, "camera")]
        self.pose = np.zeros((n, 2))  # camera yaw offset (rad), sideways offset (m, + = left)
        if any(getattr(settings, k) for k in POSE_OPTIONS):
            for cam in self.cameras:
                cam.pose_offset = self.pose
        self.image = any(getattr(settings, k) for k in IMAGE_OPTIONS)

    @property
    def space(self):
        return self.inner.space

    def __call__(self, rows=None):
        idx = np.arange(self.sim.num_cars) if rows is None else np.asarray(rows, dtype=np.int64)
        fresh = idx[self.sim.ctr[idx, K.KSTEPS] == 0]
        if fresh.size:
            self._draw(fresh)
        obs = self.inner(rows) if rows is not None else self.inner()
        if isinstance(obs, dict):
            for key, value in obs.items():
                self._perturb(key, value, idx)
        else:
            self._perturb(self.name, obs, idx)
        return obs

    def _draw(self, cars: np.ndarray) -> None:
        s, rng, n = self.s, self.rng, cars.size
        self.sigma[cars] = rng.uniform(0.0, s.blur, n) if s.blur else 0.0
        self.gain[cars] = _gains(rng, n, s.exposure)
        self.gamma[cars] = _gains(rng, n, s.gamma)
        if s.pose_pitch_deg:
            pitch = np.radians(rng.uniform(-s.pose_pitch_deg, s.pose_pitch_deg, n))
            self.row_shift[cars] = np.rint(_focal_px() * np.tan(pitch)).astype(np.int64)
        self.pose[cars, 0] = np.radians(rng.uniform(-s.pose_yaw_deg, s.pose_yaw_deg, n)) if s.pose_yaw_deg else 0.0
        self.pose[cars, 1] = rng.uniform(-s.pose_shift_m, s.pose_shift_m, n) if s.pose_shift_m else 0.0

    def _perturb(self, key, value: np.ndarray, idx: np.ndarray) -> None:
        base = (key or "").split(":")[0]
        if base in CAMERA_KEYS and self.image:
            value[idx] = perturb_images(value[idx], self.sigma[idx], self.gain[idx], self.gamma[idx],
                                        self.row_shift[idx], self.s.camera_noise, self.rng)
        elif base == "lidar" and self.s.lidar_noise_m:
            # the 64-ray lidar's ranges; the sector lidars' readings are thresholds of them, left alone
            space = self.inner.space[key] if hasattr(self.inner.space, "spaces") else self.inner.space
            noisy = value[idx] + self.rng.normal(0.0, self.s.lidar_noise_m, value[idx].shape).astype(value.dtype)
            value[idx] = np.clip(noisy, space.low, space.high)


def _parts(obs) -> list:
    return list(obs.parts.values()) if hasattr(obs, "parts") else [obs]


def _focal_px() -> float:
    """Pixels per unit of tan(angle) of the camera's pinhole: the image's half-width over tan(hfov / 2)."""
    from racerlab.sim.sensors.geometry import CAMERA_HFOV_RAD, IMAGE_W

    return (IMAGE_W / 2) / math.tan(CAMERA_HFOV_RAD / 2)


def perturb_images(frames: np.ndarray, sigma, gain, gamma, row_shift, noise: float, rng) -> np.ndarray:
    """(B, H, W, C) uint8 frames → perturbed copy: rows shifted (pitch), Gaussian blur of `sigma` pixels,
    v → 255·(gain·v/255)^gamma, then Gaussian noise of `noise` grey levels; rounded and clipped to uint8."""
    out = frames.astype(np.float32)
    for i in range(out.shape[0]):
        img = out[i]
        if row_shift[i]:
            img = _shift_rows(img, int(row_shift[i]))
        if sigma[i] > 0:
            img = gaussian_filter1d(gaussian_filter1d(img, sigma[i], axis=0, mode="nearest"), sigma[i], axis=1,
                                    mode="nearest")
        if gain[i] != 1 or gamma[i] != 1:
            img = 255.0 * np.clip(gain[i] * img / 255.0, 0.0, 1.0) ** gamma[i]
        out[i] = img
    if noise:
        out += rng.normal(0.0, noise, out.shape).astype(np.float32)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def _shift_rows(img: np.ndarray, k: int) -> np.ndarray:
    """Rows moved up by k (down for k < 0); the rows uncovered repeat the edge row."""
    h = img.shape[0]
    src = np.clip(np.arange(h) + k, 0, h - 1)
    return img[src]
