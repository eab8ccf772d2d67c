"""The front camera and the stereo camera (facts §4) for every car of a simulator.

`Camera` renders 160×120 greyscale frames, uint8, as AWS's camera pipeline delivers them (RGB
Y = 0.2989 R + 0.587 G + 0.114 B, truncated), from a pinhole camera 0.145 m ahead of the base origin and
`look.camera_z` above the ground (the AWS look: 0.163 m, as the simulator's frames show; the URDF gives 0.130 m),
pitched 15° down, 64.7° horizontal field of view; stereo renders two such cameras 6 cm apart into the two
channels (left eye first, as AWS stacks LEFT then RIGHT).

The world looks as `look` (a `TrackLook`) says: by default the AWS simulator's (walls, field, grainy
asphalt), `look.LOOKS["classic"]` racerlab's earlier one. With a `DomainRandomization`, each car draws a new
look (light colour and brightness, tone curve, gradient, noise strength) whenever the camera sees it at step 0
of an episode, from the simulator's seeded generator; without one every frame has the default look and no noise.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np

from racerlab.sim import _kernels as K
from racerlab.sim.sensors import _render
from racerlab.sim.sensors.geometry import (
    IMAGE_H,
    IMAGE_W,
    SKY_AZ_BINS,
    SKY_EL_STEP_RAD,
    STEREO_HALF_BASELINE_M,
    CameraModel,
    RowPlan,
    camera_position,
)
from racerlab.sim.sensors.look import DomainRandomization, Lighting, TrackLook
from racerlab.sim.sensors.solids import Solids
from racerlab.sim.sensors.texture import FINE_CELL_M, FINE_SCALE, fine_grain, track_raster

NOISE_TILES = 4  # the noise tile holds this many frames' worth of values; each frame starts at a random offset
NOISE_SEED = 15


class Camera:
    """Renders every car's camera (one or two eyes) from the simulator's current poses."""

    def __init__(self, sim, stereo: bool = False, randomization: DomainRandomization | None = None,
                 look: TrackLook | None = None, model: CameraModel | None = None):
        self.sim = sim
        self.look = look or TrackLook()
        self.model = model or CameraModel()
        self.randomization = randomization
        self.pose_offset: np.ndarray | None = None  # (B, 2) yaw (rad), sideways (m) camera offsets (sim.randomise)
        cam_x = camera_position()[0]
        sides = (STEREO_HALF_BASELINE_M, -STEREO_HALF_BASELINE_M) if stereo else (0.0,)
        self.eyes = np.array([[cam_x, y] for y in sides])
        self.solids = Solids(sim, self.look)
        self.raster = track_raster(sim.track, self.look)
        self._raster_args = self._pack_raster()
        self._world_args = self._pack_world(stereo)
        self.replan()
        n, e = sim.num_cars, len(sides)
        self.lighting = Lighting.default(n, self.look)
        npix = self.model.height * self.model.width
        # a fixed tile of unit noise, read from a random offset each frame (the offsets come from the
        # simulator's generator, so a seeded run repeats however the generator was seeded before)
        self._noise = (np.random.default_rng(NOISE_SEED).standard_normal(NOISE_TILES * npix).astype(np.float32)
                       if randomization else np.zeros(npix, dtype=np.float32))
        self._noise_off = np.zeros((n, e), dtype=np.int64)
        self.frames = np.zeros((n, self.model.height, self.model.width, e), dtype=np.uint8)
        self._all = np.arange(n, dtype=np.int64)

    def _pack_raster(self):
        r = self.raster
        g = r.grey
        gf, cf = r.fractions() if self.randomization else (g, g)
        # per level: first texel, stride, last column, last row, texels per metre (all exact in float64)
        levels = np.column_stack([g.off, g.stride, g.w - 1, g.h - 1, r.level_inv_cell]).astype(np.float64)
        return g.data, gf.data, cf.data, levels, float(r.x0), float(r.y0)

    def _pack_world(self, stereo: bool):
        look = self.look
        box = np.array(look.wall_box(self.sim.track) if look.walls else (0.0, 0.0, 0.0, 0.0))
        grainy = look.grainy
        fine = (fine_grain(look) if grainy else np.zeros((1, 1), dtype=np.int8)).ravel()
        amp = look.fine_grain_table() * np.float32(FINE_SCALE) if grainy else np.zeros(257, dtype=np.float32)
        # AWS's camera filter truncates its float grey; the stereo pair goes through PIL's convert('L'), which rounds
        return (look.walls, box, float(look.wall_height_m), fine, self.raster.cell / FINE_CELL_M, amp,
                0.5 if stereo else 0.0, look.haze_m is not None)

    def replan(self, **options) -> None:
        """Rebuild the row plan with `RowPlan` keyword options (anisotropy, max_subrows, level_bias):
        the trade between speed, blur and shimmer of distant ground."""
        cam_z = self.look.camera_z
        options.setdefault("haze_m", self.look.haze_m)
        options.setdefault("fine_cell_m", FINE_CELL_M if self.look.grainy else 0.0)
        p = self.plan = RowPlan(self.model, cam_z, self.raster.cell, self.raster.num_levels, self.look.filter_px,
                                **options)
        self.panorama = self.look.panorama(SKY_EL_STEP_RAD, p.sky_el_bins, SKY_AZ_BINS)
        self._cam_args = (cam_z, self.model.focal_px, math.cos(self.model.pitch_rad), math.sin(self.model.pitch_rad))
        # one row per ground line, in the renderer's order (`_render._lines`)
        lines = np.column_stack([p.sub_x, p.sub_y0, p.sub_dy, p.sub_level, p.sub_step, p.sub_weight, p.sub_fine])
        self._plan_args = (p.row_first, p.row_haze, p.row_sky, np.ascontiguousarray(lines, dtype=np.float64),
                           p.sky_el, p.sky_az, p.edge_dir)

    @property
    def channels(self) -> int:
        return int(self.eyes.shape[0])

    def render(self, rows=None) -> np.ndarray:
        """Render cars `rows` (all by default) into `self.frames` (B, H, W, eyes) and return it (not a copy)."""
        idx = self._all if rows is None else np.ascontiguousarray(rows, dtype=np.int64)
        if self.randomization is not None:
            self._randomize(idx)
        lg = self.lighting
        lit = (lg.plain, lg.coef, lg.tone, lg.light, lg.noise_amp, self._noise, self._noise_off)
        sol = self.solids
        sol.update()
        x, y, yaw = self._viewpoints()
        _render.render(idx, x, y, yaw, self.eyes, self._plan_args, self._raster_args, self.panorama, lit,
                       (sol.pose, sol.dims, sol.grey, self._cam_args), self._world_args, self.frames)
        return self.frames

    def _viewpoints(self):
        """Every car's base pose (x, y, yaw) as the camera sees from it: the car's, moved by `pose_offset`."""
        car = self.sim.car
        x, y, yaw = car[:, K.CX], car[:, K.CY], car[:, K.CYAW]
        if self.pose_offset is None:
            return x, y, yaw
        d_yaw, side = self.pose_offset[:, 0], self.pose_offset[:, 1]
        return x - side * np.sin(yaw), y + side * np.cos(yaw), yaw + d_yaw

    def _randomize(self, idx: np.ndarray) -> None:
        """A new look for cars at step 0 of an episode, fresh noise offsets for every rendered car."""
        rng = self.sim.rng
        fresh = idx[self.sim.ctr[idx, K.KSTEPS] == 0]
        light = self.lighting.draw(fresh, self.randomization, self.look, rng)
        if light is not None:  # AWS gives every obstacle, and each visual of a bot car, a random colour
            self.solids.recolour(fresh, light, rng)
        npix = self.model.height * self.model.width
        self._noise_off[idx] = rng.integers(0, self._noise.size - npix, size=(idx.size, self.channels))


class CameraObservation:
    """`camera` (120, 160, 1) or `stereo` (120, 160, 2) uint8 frames of every car."""

    partial_update = True

    def __init__(self, sim, stereo: bool = False, randomization: DomainRandomization | None = None,
                 look: TrackLook | None = None):
        self.name = "stereo" if stereo else "camera"
        self.camera = Camera(sim, stereo=stereo, randomization=randomization, look=look)

    @property
    def space(self) -> gym.Space:
        return gym.spaces.Box(0, 255, shape=(IMAGE_H, IMAGE_W, self.camera.channels), dtype=np.uint8)

    def __call__(self, rows=None) -> np.ndarray:
        # a copy: callers keep observations across steps while the camera renders into its own buffer
        return self.camera.render(rows).copy()
