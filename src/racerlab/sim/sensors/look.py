"""How the world looks to the camera: paint and colours of the track, ground and background, and the
per-episode domain randomization of that look.

AWS does not publish its track textures (facts §13), so these are racerlab's choices, made to
give greyscale frames with the contrast of AWS's: a dark road, 5 cm white border lines painted
just inside each border, a dashed orange-yellow centre line that turns mid grey, green-grey ground,
a darker skyline band (walls, trees, buildings) and a light sky. Colours are RGB in [0, 255];
`grey()` turns them into the AWS camera's Y = 0.2989 R + 0.587 G + 0.114 B.

Domain randomization (`DomainRandomization`) follows what DRfC's `ENABLE_DOMAIN_RANDOMIZATION`
does (facts §11: every light gets a random colour and attenuation before each episode) in the
terms a greyscale camera can tell apart: a light colour and brightness (which change the grey of
each material differently: a blue-ish light darkens the yellow centre line and the green ground
more than the white lines), a tone curve (contrast and gamma), a brightness gradient across the
image (a light off to one side) and sensor noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LUMA = np.array([0.2989, 0.5870, 0.1140])

# material order in TrackLook.colors()
ROAD, LINE, CENTER, GROUND, SKY, SKYLINE, HAZE = range(7)
N_MATERIALS = 7


@dataclass(frozen=True)
class TrackLook:
    """Paint geometry and material colours (RGB 0-255) of the rendered world."""

    line_width_m: float = 0.05
    center_width_m: float = 0.05
    dash_m: float = 0.15
    gap_m: float = 0.15
    road: tuple = (42, 42, 46)
    line: tuple = (236, 236, 236)
    center: tuple = (235, 170, 40)
    ground: tuple = (96, 142, 82)
    sky: tuple = (200, 210, 222)
    skyline: tuple = (84, 90, 96)
    haze: tuple = (165, 175, 180)
    box: tuple = (200, 160, 110)  # obstacles: cardboard, light against the road
    bot_car: tuple = (90, 100, 190)  # bot cars: blue, between the road and the box in grey
    tyre: tuple = (30, 30, 34)  # a bot car's wheels
    skyline_seed: int = 2018
    # effective width of AWS's 640×480 → 160×120 PIL bilinear resize filter, in output pixels
    filter_px: float = 1.4

    def colors(self) -> np.ndarray:
        """(N_MATERIALS, 3) RGB in material order."""
        return np.array([self.road, self.line, self.center, self.ground, self.sky, self.skyline, self.haze],
                        dtype=np.float64)

    def grey(self) -> np.ndarray:
        """(N_MATERIALS,) greyscale value of each material under white light."""
        return self.colors() @ LUMA

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


@dataclass(frozen=True)
class DomainRandomization:
    """Ranges of the camera's per-episode look; each car draws its own at the start of every episode.

    - `brightness`: gain of the light (1 = the default look);
    - `tint`: each RGB channel of the light colour is scaled by a draw from this range (then the
      colour is normalised to its brightest channel), so materials change grey by their colour;
    - `contrast`: slope of the tone curve around mid grey; `gamma`: its exponent;
    - `gradient`: the gain changes linearly by up to this fraction from the image centre to its
      left/right and top/bottom edges (a light off to one side);
    - `noise_sigma`: the standard deviation of per-pixel Gaussian noise, grey levels, drawn from
      [0, noise_sigma] per episode; fresh noise every frame.

    The defaults are racerlab's choice (AWS gives lights a uniform random colour and attenuation
    in [0, 1] but publishes no resulting image statistics); they keep the road darker than the
    lines in almost every draw, as in AWS's randomized frames.
    """

    brightness: tuple[float, float] = (0.55, 1.35)
    tint: tuple[float, float] = (0.55, 1.0)
    contrast: tuple[float, float] = (0.7, 1.3)
    gamma: tuple[float, float] = (0.75, 1.35)
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
    coef: np.ndarray  # (B, 5) neutral gain, ground and centre corrections, haze grey, sky gain
    tone: np.ndarray  # (B, 257) float32 tone curve over greys 0..256 (the last entry repeats 255's)
    light: np.ndarray  # (B, 3) gain at the image centre and its change to the right / bottom edge
    noise_amp: np.ndarray  # (B,) noise standard deviation, grey levels

    @classmethod
    def default(cls, num_cars: int, look: TrackLook) -> Lighting:
        g = look.grey()
        coef = np.zeros((num_cars, 5))
        coef[:, 0] = 1.0
        coef[:, 3] = g[HAZE]
        coef[:, 4] = 1.0
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
        tint /= tint.max(axis=1, keepdims=True)
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

