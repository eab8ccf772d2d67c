"""How the world looks to the camera: paint and colours of the track, ground, walls and background, the grain
of their textures, and the per-episode domain randomization of that look.

The default look (`TrackLook()`, also `LOOKS["aws"]`) is the AWS simulator's, worked out from its real camera
frames (`../shared/reference/gazebo_frames`: what the simapp's 640×480 Gazebo camera gives after the resize to
160×120 and the greyscale filter) and from its reInvent track model (simapp `bundle/meshes/reinvent/`):

- geometry from the track mesh: white border lines 3 in (7.62 cm) wide painted inside each border, a dashed
  centre line 1 in (2.54 cm) wide of 2 in (5.08 cm) dashes and 2 in gaps, a field around the track and a wall
  1 m high around the field, 0.91 m beyond the track's bounding box (the field and wall meshes);
- the grey of each material as the real frames show it under the simulator's lights: asphalt 85, field 166,
  white lines 254 (the texture saturates), centre line 190, walls 84; above the walls Gazebo's default
  background grey (0.7: 178). The colours keep the hue of the simapp's textures (dark blue asphalt, green
  field, orange centre line, dark teal walls), scaled to those greys, so that a coloured light in domain
  randomization changes each material as it would;
- the camera 0.163 m above the ground, not the URDF's 0.130 m (`camera_height_m`): the real frames show the
  ground as from that height, by three measures that agree (the stereo pairs' disparity grows 0.356 px per
  row below the horizon, B·cos 15°/h with the 6 cm baseline, where 0.130 m gives 0.446; the centre line's 4 in
  dash period and its 1 in width come out 0.79× and 0.8× what 0.130 m predicts). Why the simulator's camera
  sits higher is not in the sources read (the car's suspension or wheels in Gazebo, perhaps); the frames rule;
- a grain fixed to the ground, as the textures have (`grain_*`): a fine pixel-scale part that near rows show,
  and a coarser blotchy part that survives to the distance. Its strength per material is fitted to the real
  frames (asphalt σ ≈ 5, field up to σ ≈ 17 grey levels near the car); no haze (Gazebo draws none).

`LOOKS["classic"]` is racerlab's earlier look (a dark road with 5 cm lines, a light sky with a skyline, haze),
kept for models trained with it. Colours are RGB in [0, 255]; `grey()` turns them into the AWS camera's
Y = 0.2989 R + 0.587 G + 0.114 B.

Domain randomization (`DomainRandomization`) follows what DRfC's `ENABLE_DOMAIN_RANDOMIZATION`
does (facts §11: every light gets a random colour and attenuation before each episode) in the
terms a greyscale camera can tell apart: a light colour and brightness (which change the grey of
each material differently: a blue-ish light darkens the orange centre line and the green field
more than the white lines), a tone curve (contrast and gamma), a brightness gradient across the
image (a light off to one side) and sensor noise. Every range is centred on the default look.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from racerlab.model.config import LOOKS as LOOK_NAMES
from racerlab.sim.sensors.geometry import AWS_CAMERA_HEIGHT_M, camera_position

LUMA = np.array([0.2989, 0.5870, 0.1140])

# material order in TrackLook.colors()
ROAD, LINE, CENTER, GROUND, SKY, SKYLINE, HAZE, WALL = range(8)
N_MATERIALS = 8


def _tint(rgb, grey: float) -> tuple:
    """The colour of hue `rgb` whose grey is `grey`, channels kept within 255 (the others make up the rest)."""
    c = np.asarray(rgb, dtype=np.float64) * grey / (np.asarray(rgb, dtype=np.float64) @ LUMA)
    for _ in range(3):
        over = c > 255.0
        if not over.any():
            break
        c[over] = 255.0
        free = ~over
        c[free] *= (grey - c[over] @ LUMA[over]) / (c[free] @ LUMA[free])
    return tuple(round(float(v), 2) for v in c)


# the simapp's reInvent textures' mean colours (road, field, centre line, wall), for their hues
ASPHALT_HUE, FIELD_HUE, CENTER_HUE, WALL_HUE = (36.1, 48.5, 64.0), (95.2, 135.6, 104.3), (194.4, 116.5, 0.0), \
    (36.0, 70.0, 81.0)
INCH_M = 0.0254


@dataclass(frozen=True)
class TrackLook:
    """Paint geometry, material colours (RGB 0-255), grain, walls and haze of the rendered world (see the module
    docstring; the defaults are the AWS simulator's)."""

    line_width_m: float = 3 * INCH_M
    center_width_m: float = 1 * INCH_M
    dash_m: float = 2 * INCH_M
    gap_m: float = 2 * INCH_M
    road: tuple = _tint(ASPHALT_HUE, 85.0)
    line: tuple = (254.0, 254.0, 254.0)
    center: tuple = _tint(CENTER_HUE, 190.0)
    ground: tuple = _tint(FIELD_HUE, 166.0)
    sky: tuple = (179, 179, 179)  # Gazebo's default background, 0.7 grey (178.5, a uint8 179), above the walls
    skyline: tuple = (84, 90, 96)
    haze: tuple = (165, 175, 180)
    wall: tuple = _tint(WALL_HUE, 84.0)
    box: tuple = (200, 160, 110)  # obstacles: cardboard, light against the road
    bot_car: tuple = (90, 100, 190)  # bot cars: blue, between the road and the box in grey
    tyre: tuple = (30, 30, 34)  # a bot car's wheels
    skyline_seed: int = 2018
    # effective width of AWS's 640×480 → 160×120 PIL bilinear resize filter, in output pixels
    filter_px: float = 1.4
    # walls around the field: this far beyond the track's bounding box, this high; None: an open horizon with
    # the skyline panorama
    wall_margin_m: float | None = 0.91
    wall_height_m: float = 1.0
    # the ground fades into the haze colour from haze_m[0] to haze_m[1] ahead; None: no haze
    haze_m: tuple | None = None
    # grain, as a fraction of each material's grey (road, line, centre, ground): the fine part's standard
    # deviation at the pixel scale of the nearest rows, the blotchy part's over a few centimetres
    grain_fine: tuple = (0.06, 0.0, 0.02, 0.17)
    grain_blotch: tuple = (0.045, 0.0, 0.01, 0.04)
    grain_seed: int = 2019
    # the camera's height above the ground, m, as the AWS simulator's frames show it (see the module docstring);
    # None: the URDF's (`geometry.camera_position`, 0.130 m)
    camera_height_m: float | None = AWS_CAMERA_HEIGHT_M

    def colors(self) -> np.ndarray:
        """(N_MATERIALS, 3) RGB in material order."""
        return np.array([self.road, self.line, self.center, self.ground, self.sky, self.skyline, self.haze,
                         self.wall], dtype=np.float64)

    def grey(self) -> np.ndarray:
        """(N_MATERIALS,) greyscale value of each material under white light."""
        return self.colors() @ LUMA

    @property
    def camera_z(self) -> float:
        """The camera's height above the ground, m."""
        return camera_position()[1] if self.camera_height_m is None else float(self.camera_height_m)

    @property
    def walls(self) -> bool:
        return self.wall_margin_m is not None

    @property
    def grainy(self) -> bool:
        return any(self.grain_fine) or any(self.grain_blotch)

    def wall_box(self, track) -> tuple[float, float, float, float]:
        """(x min, y min, x max, y max) of the walls around `track`, m."""
        pts = np.vstack([track.inner, track.outer])
        lo, hi = pts.min(axis=0) - self.wall_margin_m, pts.max(axis=0) + self.wall_margin_m
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    def fine_grain_table(self) -> np.ndarray:
        """(257,) float32: the fine grain's standard deviation, grey levels, over the grey read from the raster
        (0..256): each material's fraction of its grey, interpolated between the materials' greys."""
        g = self.grey()[[ROAD, CENTER, GROUND, LINE]]
        amp = np.array(self.grain_fine)[[0, 2, 3, 1]] * g
        order = np.argsort(g)
        v = np.minimum(np.arange(257), 255).astype(np.float64)
        return np.interp(v, g[order], amp[order]).astype(np.float32)

    def object_grey(self, bot_car: bool = False) -> float:
        """Grey under white light of an obstacle box, or of a bot car's body."""
        return float(np.asarray(self.bot_car if bot_car else self.box, dtype=np.float64) @ LUMA)

    def material_grey(self, name: str) -> float:
        """Grey under white light of the look's colour `name` ("box", "bot_car", "tyre", ...)."""
        return float(np.asarray(getattr(self, name), dtype=np.float64) @ LUMA)

    def skyline_profile(self, bins: int = 1024) -> np.ndarray:
        """(bins,) elevation (rad) of the skyline over azimuth 0..2π: a band of blocks and hills."""
        rng = np.random.default_rng(self.skyline_seed)
        az = np.arange(bins) * (2 * np.pi / bins)
        hills = 0.03 + 0.015 * np.sin(3 * az + 1.0) + 0.01 * np.sin(7 * az + 2.0)
        blocks = np.zeros(bins)
        k = 0
        while k < bins:
            w = int(rng.integers(8, 40))
            h = rng.uniform(0.0, 0.09) if rng.random() < 0.6 else 0.0
            blocks[k:k + w] = h
            k += w + int(rng.integers(0, 12))
        return np.maximum(hills, blocks).astype(np.float64)

    def panorama(self, el_step_rad: float, el_bins: int, az_bins: int = 1024) -> np.ndarray:
        """(el_bins, az_bins + 1) greys of the background above the horizon under white light.

        Row k covers elevations [k, k+1) · el_step from the horizon up; column j azimuth
        j · 2π / az_bins counter-clockwise from the world's +x (the last column repeats the first,
        so a renderer can interpolate without wrapping). The skyline edge is anti-aliased by the
        fraction of each cell it covers.
        """
        g = self.grey()
        top = self.skyline_profile(az_bins)
        lo = np.arange(el_bins)[:, None] * el_step_rad
        cover = np.clip((top[None, :] - lo) / el_step_rad, 0.0, 1.0)
        mid = lo + 0.5 * el_step_rad
        sky = g[HAZE] + (g[SKY] - g[HAZE]) * np.clip(mid * 6.0, 0.0, 1.0)
        pano = sky + (g[SKYLINE] - sky) * cover
        return np.ascontiguousarray(np.hstack([pano, pano[:, :1]]), dtype=np.float32)



CLASSIC = dict(line_width_m=0.05, center_width_m=0.05, dash_m=0.15, gap_m=0.15, road=(42, 42, 46),
               line=(236, 236, 236), center=(235, 170, 40), ground=(96, 142, 82), sky=(200, 210, 222),
               wall_margin_m=None, haze_m=(4.0, 30.0), grain_fine=(0.0, 0.0, 0.0, 0.0),
               grain_blotch=(0.0, 0.0, 0.0, 0.0), camera_height_m=None)
LOOKS = dict(zip(LOOK_NAMES, (TrackLook(), replace(TrackLook(), **CLASSIC)), strict=True))  # run.look's names


@dataclass(frozen=True)
class DomainRandomization:
    """Ranges of the camera's per-episode look; each car draws its own at the start of every episode.

    - `brightness`: gain of the light (1 = the default look);
    - `tint`: each RGB channel of the light colour is scaled by a draw from this range (then the
      colour is normalised to a neutral grey's gain of 1), so materials change grey by their colour;
    - `contrast`: slope of the tone curve around mid grey; `gamma`: its exponent;
    - `gradient`: the gain changes linearly by up to this fraction from the image centre to its
      left/right and top/bottom edges (a light off to one side);
    - `noise_sigma`: the standard deviation of per-pixel Gaussian noise, grey levels, drawn from
      [0, noise_sigma] per episode; fresh noise every frame.

    The ranges are racerlab's choice (AWS gives lights a uniform random colour and attenuation
    in [0, 1] but publishes no resulting image statistics), centred on the default look: brightness
    and contrast around 1, gamma from 0.8 to 1.2 (which leaves mid greys where they were on average),
    a tint that keeps a neutral grey's level, a gradient either way. Averaged over draws, a frame's
    greys are the default look's but for the white lines' light clipped at 255, about 3 grey levels
    darker over a frame (`tests/sim/test_sensors.py`); the road stays darker than the lines in
    almost every draw.
    """

    brightness: tuple[float, float] = (0.7, 1.3)
    tint: tuple[float, float] = (0.6, 1.0)
    contrast: tuple[float, float] = (0.7, 1.3)
    gamma: tuple[float, float] = (0.8, 1.2)
    gradient: float = 0.25
    noise_sigma: float = 6.0

    def __post_init__(self):
        for name in ("brightness", "tint", "contrast", "gamma"):
            lo, hi = getattr(self, name)
            if not 0.0 < lo <= hi:
                raise ValueError(f"DomainRandomization.{name} must be a range 0 < low <= high, got {(lo, hi)}")
        if not 0.0 <= self.gradient < 1.0 or self.noise_sigma < 0.0:
            raise ValueError("DomainRandomization: gradient must be in [0, 1) and noise_sigma >= 0")


@dataclass
class Lighting:
    """Per-car lighting arrays the renderer reads (B rows); `plain[i]` skips every per-pixel change."""

    plain: np.ndarray  # (B,) bool: the default look, no tone curve, gradient or noise
    coef: np.ndarray  # (B, 7) neutral gain, ground and centre corrections, haze grey, sky gain, wall and sky greys
    tone: np.ndarray  # (B, 257) float32 tone curve over greys 0..256 (the last entry repeats 255's)
    light: np.ndarray  # (B, 3) gain at the image centre and its change to the right / bottom edge
    noise_amp: np.ndarray  # (B,) noise standard deviation, grey levels

    @classmethod
    def default(cls, num_cars: int, look: TrackLook) -> Lighting:
        g = look.grey()
        coef = np.zeros((num_cars, 7))
        coef[:, 0] = 1.0
        coef[:, 3] = g[HAZE]
        coef[:, 4] = 1.0
        coef[:, 5] = g[WALL]
        coef[:, 6] = g[SKY]
        tone = np.tile(np.minimum(np.arange(257), 255).astype(np.float32), (num_cars, 1))
        light = np.zeros((num_cars, 3))
        light[:, 0] = 1.0
        return cls(np.ones(num_cars, dtype=bool), coef, tone, light, np.zeros(num_cars))

    def draw(self, rows: np.ndarray, dr: DomainRandomization, look: TrackLook,
             rng: np.random.Generator) -> np.ndarray | None:
        """New random looks for cars `rows` (one draw each from `rng`); returns their lights' RGB gains (n, 3)."""
        n = rows.size
        if n == 0:
            return None
        tint = rng.uniform(*dr.tint, size=(n, 3))
        tint /= (tint @ LUMA)[:, None]  # a neutral grey keeps its level: the tint changes colours only
        light_rgb = tint * rng.uniform(*dr.brightness, size=(n, 1))
        cols = look.colors()
        lit = (light_rgb[:, None, :] * cols[None, :, :]) @ LUMA  # (n, materials) grey under that light
        neutral = light_rgb @ LUMA
        white = look.grey()
        self.coef[rows, 0] = neutral
        self.coef[rows, 1] = lit[:, GROUND] - neutral * white[GROUND]
        self.coef[rows, 2] = lit[:, CENTER] - neutral * white[CENTER]
        self.coef[rows, 3] = lit[:, HAZE]
        self.coef[rows, 4] = lit[:, SKY] / white[SKY]
        self.coef[rows, 5] = lit[:, WALL]
        self.coef[rows, 6] = lit[:, SKY]
        self.tone[rows] = tone_curves(rng.uniform(*dr.contrast, size=n), rng.uniform(*dr.gamma, size=n))
        self.light[rows, 0] = 1.0
        self.light[rows, 1:] = rng.uniform(-dr.gradient, dr.gradient, size=(n, 2))
        self.noise_amp[rows] = rng.uniform(0.0, dr.noise_sigma, size=n)
        self.plain[rows] = False
        return light_rgb


def tone_curves(contrast: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """(n, 257) float32: grey v → 255 · ((v/255)^gamma − ½) · contrast + ½), clipped to [0, 255]."""
    v = np.minimum(np.arange(257), 255) / 255.0
    g = v[None, :] ** np.asarray(gamma)[:, None]
    out = ((g - 0.5) * np.asarray(contrast)[:, None] + 0.5) * 255.0
    return np.clip(out, 0.0, 255.0).astype(np.float32)

