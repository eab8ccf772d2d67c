"""Domain randomisation for the physical car: what a `World` changes between the policy and the simulator.

`training.toml`'s `[randomise]` table (`racerlab.model.config.RandomiseSettings`) names the options; the
two classes here apply them to a batch of cars, drawing from one seeded generator:

- `Actuation` (World.step): the car's speed mapping (speeds relative to the action space's top speed,
  scaled to `top_speed` × `speed_scale`), per-episode steering and throttle gains, and a delay of 0-2
  steps between the action chosen and the action applied (with `latency_varies`, each episode's own
  delay drawn from 0 to `latency_steps`);
- `RandomisedObservation` (World.observe): per-episode camera pose (yaw and sideways offset move the
  rendered viewpoint; pitch shifts the image rows), blur, exposure and gamma, per-frame pixel noise (each
  frame a random cyclic shift of one of NOISE_FIELDS unit-noise fields drawn once), and lidar range noise.
  `lighting` is the camera's own per-episode look (`camera:dr`, set by the World).

A car's episode starts when its step counter is 0: that is when its per-episode values are drawn. With
every option at its default the World builds neither, and the plain path runs unchanged.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

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
        self.delay = np.full(num_cars, settings.latency_steps, dtype=np.int64)  # each car's latency, steps

    def __call__(self, steer: np.ndarray, speed: np.ndarray, steps: np.ndarray, active=None):
        """Applied (steering, speed) for the cars in `active` (all by default); `steps` is each car's step
        counter before this step (0 = the first step of an episode, AWS's prepare step)."""
        idx = np.arange(steer.size) if active is None else np.flatnonzero(active)
        cmd = np.stack([steer[idx], speed[idx] * self.speed_factor], axis=1)
        fresh = idx[steps[idx] == 0]
        if fresh.size:
            self.gain[fresh, 0] = _gains(self.rng, fresh.size, self.s.steering_gain)
            self.gain[fresh, 1] = _gains(self.rng, fresh.size, self.s.throttle_gain)
            if self.s.latency_varies:
                self.delay[fresh] = self.rng.integers(0, self.s.latency_steps + 1, size=fresh.size)
            self.history[fresh] = cmd[np.searchsorted(idx, fresh)][:, None, :]
        hist = self.history[idx]
        hist[:, 1:] = hist[:, :-1]
        hist[:, 0] = cmd
        self.history[idx] = hist
        applied = hist[np.arange(idx.size), self.delay[idx]] * self.gain[idx]
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
        self.fields = None  # unit-noise fields of this observation's camera frames (`perturb_images`)

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
            if self.s.camera_noise and self.fields is None:
                self.fields = self.rng.standard_normal((NOISE_FIELDS, *value.shape[1:]), dtype=np.float32)
            value[idx] = perturb_images(value[idx], self.sigma[idx], self.gain[idx], self.gamma[idx],
                                        self.row_shift[idx], self.s.camera_noise, self.rng, self.fields)
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


NOISE_FIELDS = 16  # per-pixel noise comes from this many fields of unit noise, drawn once per observation


def perturb_images(frames: np.ndarray, sigma, gain, gamma, row_shift, noise: float, rng,
                   fields: np.ndarray | None = None) -> np.ndarray:
    """(B, H, W, C) uint8 frames → perturbed copy: rows shifted (pitch), Gaussian blur of `sigma` pixels,
    v → 255·(gain·v/255)^gamma, then Gaussian noise of `noise` grey levels; rounded and clipped to uint8.

    One compiled pass per frame (`_perturb`): the blur is scipy's (`gaussian_filter1d`, truncated at 4 sigma,
    edges repeated), the tone curve a 257-entry table read with linear interpolation (exact at whole greys), the
    noise each frame's own cyclic shift of one of `fields` (unit-noise fields, (F, H, W, C) float32; NOISE_FIELDS
    drawn from `rng` when None). On a busy 2-core machine this took 0.13 ms a frame where NumPy and scipy per
    image took 1.8 ms."""
    frames = np.ascontiguousarray(frames)
    b, h, w, c = frames.shape
    sigma, gain, gamma = (np.broadcast_to(np.asarray(x, dtype=np.float64), (b,)) for x in (sigma, gain, gamma))
    shift = np.broadcast_to(np.asarray(row_shift, dtype=np.int64), (b,))
    radius = max(int(4.0 * float(sigma.max()) + 0.5), 0) if b else 0
    weights = np.zeros((b, 2 * radius + 1))
    for i in range(b):
        weights[i] = _gaussian_weights(float(sigma[i]), radius)
    grey = np.arange(257, dtype=np.float64)
    tone = 255.0 * np.clip(gain[:, None] * np.minimum(grey, 255.0)[None, :] / 255.0, 0.0, 1.0) ** gamma[:, None]
    if noise and fields is None:
        fields = rng.standard_normal((NOISE_FIELDS, h, w, c), dtype=np.float32)
    if noise:
        pick = rng.integers(0, len(fields), size=b)
        offset = np.stack([rng.integers(0, h, size=b), rng.integers(0, w, size=b)], axis=1)
    else:
        fields, pick, offset = np.zeros((1, 1, 1, 1), np.float32), np.zeros(b, np.int64), np.zeros((b, 2), np.int64)
    out = np.empty_like(frames)
    _perturb(frames, shift, weights, np.ascontiguousarray(sigma), tone, float(noise), fields, pick, offset, out)
    return out


def _gaussian_weights(sigma: float, radius: int) -> np.ndarray:
    """scipy's 1-D Gaussian kernel of `sigma` (truncated at 4 sigma), centred in 2 * radius + 1 taps."""
    out = np.zeros(2 * radius + 1)
    if sigma <= 0:
        out[radius] = 1.0
        return out
    r = int(4.0 * sigma + 0.5)
    x = np.arange(-r, r + 1)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    out[radius - r:radius + r + 1] = k / k.sum()
    return out


@njit(cache=True)
def _perturb(frames, shift, weights, sigma, tone, noise, fields, pick, offset, out):  # pragma: no cover - compiled
    b, h, w, c = frames.shape
    rows = np.empty((h, w), np.float64)
    cols = np.empty((h, w), np.float64)
    for i in range(b):
        for ch in range(c):
            for y in range(h):
                src = min(max(y + shift[i], 0), h - 1)
                for x in range(w):
                    rows[y, x] = frames[i, src, x, ch]
            if sigma[i] > 0.0:
                _blur(rows, cols, weights[i], int(4.0 * sigma[i] + 0.5))
            _tone(rows, tone[i], noise, fields[pick[i], :, :, ch], offset[i, 0], offset[i, 1], out[i, :, :, ch])


@njit(cache=True, fastmath=True)
def _blur(img, tmp, weights, r):  # pragma: no cover - compiled
    """`img` blurred in place by the `weights` within r taps of their centre, down the columns (into `tmp`) and
    then along the rows; edges repeated."""
    h, w = img.shape
    c = (weights.shape[0] - 1) // 2
    for y in range(h):
        for x in range(w):
            acc = 0.0
            for k in range(-r, r + 1):
                acc += weights[c + k] * img[min(max(y + k, 0), h - 1), x]
            tmp[y, x] = acc
    for y in range(h):
        for x in range(w):
            acc = 0.0
            for k in range(-r, r + 1):
                acc += weights[c + k] * tmp[y, min(max(x + k, 0), w - 1)]
            img[y, x] = acc


@njit(cache=True)
def _tone(img, tone, noise, field, dy, dx, out):  # pragma: no cover - compiled
    """The tone table read at each grey (linear between whole greys), the noise field added from (dy, dx) on,
    rounded and clipped into `out`."""
    h, w = img.shape
    for y in range(h):
        fy = y + dy - h if y + dy >= h else y + dy
        for x in range(w):
            v = min(max(img[y, x], 0.0), 255.0)
            j = min(int(v), 255)
            t = tone[j] + (v - j) * (tone[j + 1] - tone[j])
            if noise > 0.0:
                fx = x + dx - w if x + dx >= w else x + dx
                t += noise * field[fy, fx]
            out[y, x] = min(max(int(np.rint(t)), 0), 255)
