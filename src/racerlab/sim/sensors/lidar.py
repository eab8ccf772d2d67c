"""The lidar and the sector lidar (facts §4) for every car of a simulator.

AWS's lidar has 64 rays from −150° to +150° in a laser frame turned by π, mounted 0.029 m ahead of
the base origin: ray 0 looks 30° left of ahead, the sweep passes the left side, the rear and the
right side, and ray 63 looks 30° right; the 60° gap is ahead, where the camera looks. Ranges get
Gaussian noise (σ = 0.01 m) and are clipped to [0.15, 1.0] m; a ray that hits nothing reads 1.0.

What the rays hit:
- the race's objects: each car's own boxes or bot cars (the simulator's `ObjectSet`, read at every
  scan: they move at resets, and bot cars drive), as oriented rectangles of the box model
  (0.40 × 0.30 m) or the car's footprint;
- other rectangles `[x, y, yaw_rad, length_m, width_m]` set with `Lidar.set_objects` (none by
  default), seen by every car or as a `visible` mask says;
- the track borders, as walls, only with `walls=True`. AWS's tracks are flat paint with no
  walls, so its lidar sees nothing there and reads 1.0; walls are a racerlab option for
  lidar-only experiments.

The sector lidar splits the 64 rays into 8 sectors of 8 consecutive rays and reads 1 where the
sector's smallest range is below 0.5 m, else 0. The discretized sector lidar (AWS's
`ObservationSectorDiscretizeFilter`) takes each sector's smallest range, up to `clipping_dist`, and
one-hot encodes it in `num_values_per_sector` equal bins; a sector that sees nothing closer than
`clipping_dist` reads all zeros. Its settings come from `lidar_config` in `model_metadata.json`.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
from numba import njit

from racerlab.errors import ConfigError
from racerlab.sim import _kernels as K
from racerlab.sim.sensors.geometry import (
    LIDAR_MAX_ANGLE_RAD,
    LIDAR_MIN_ANGLE_RAD,
    LIDAR_RAYS,
    LIDAR_YAW_RAD,
    lidar_position,
    lidar_ray_angles,
)

MIN_RANGE_M, MAX_RANGE_M = 0.15, 1.0  # AWS ObservationClippingFilter
NOISE_SIGMA_M = 0.01
LIDAR_STEP_RAD = (LIDAR_MAX_ANGLE_RAD - LIDAR_MIN_ANGLE_RAD) / (LIDAR_RAYS - 1)
LIDAR_STEP_COS, LIDAR_STEP_SIN = math.cos(LIDAR_STEP_RAD), math.sin(LIDAR_STEP_RAD)
SECTORS = 8
SECTOR_CLIP_M = 0.5
NOISE_REACH_SIGMAS = 6  # a hit further than max range + 6 σ reads max range whatever the noise
GRID_CELL_M = 0.25
GAZEBO_RANGE_M = (0.15, 12.0)  # the simulated sensor's own range (facts §4)
# AWS DiscretizedSectorLidarDefaults (boto/s3/constants.py)
DISCRETIZED_DEFAULTS = {"num_sectors": 8, "num_values_per_sector": 8, "clipping_dist": 2.0}


@njit(cache=True, inline="always")
def _ray_segment(ox, oy, dx, dy, ax, ay, bx, by):
    """Distance along the unit ray (ox, oy) + t (dx, dy) to segment a-b; inf if missed."""
    ex = bx - ax
    ey = by - ay
    den = dx * ey - dy * ex
    if abs(den) < 1e-15:
        return np.inf
    qx = ax - ox
    qy = ay - oy
    t = (qx * ey - qy * ex) / den
    u = (qx * dy - qy * dx) / den
    if t >= 0.0 and -1e-12 <= u <= 1.0 + 1e-12:
        return t
    return np.inf


@njit(cache=True, inline="always")
def _turn(step):
    """(cos, sin) of the angle between neighbouring rays, worked out once for the scan's own step."""
    if step == LIDAR_STEP_RAD:
        return LIDAR_STEP_COS, LIDAR_STEP_SIN
    return math.cos(step), math.sin(step)


@njit(cache=True, inline="always")
def _hit_rays(ox, oy, base, step, nrays, lo, hi, ax, ay, bx, by, best):
    """Intersect rays lo..hi (indices, clipped to the scan) with segment a-b; keep the nearer hits in best."""
    k0 = max(lo, 0)
    k1 = min(hi, nrays - 1)
    if k1 < k0:
        return
    # ray directions by rotation from the first one: two sines per segment, not two per ray
    c0 = math.cos(base + k0 * step)
    s0 = math.sin(base + k0 * step)
    cs, ss = _turn(step)
    for k in range(k0, k1 + 1):
        t = _ray_segment(ox, oy, c0, s0, ax, ay, bx, by)
        if t < best[k]:
            best[k] = t
        c0, s0 = c0 * cs - s0 * ss, s0 * cs + c0 * ss


@njit(cache=True, inline="always")
def _cast(ox, oy, base, step, nrays, reach, ax, ay, bx, by, best):
    """Cast segment a-b onto the rays it can meet: those within the angle it spans seen from (ox, oy).

    Ray k points at world angle base + k·step; a segment further than `reach` is skipped.
    """
    ex = bx - ax
    ey = by - ay
    ll = ex * ex + ey * ey
    t = min(max(((ox - ax) * ex + (oy - ay) * ey) / ll, 0.0), 1.0) if ll > 0.0 else 0.0
    # every hit is at least as far as the segment's nearest point: beyond reach (a hair kept for rounding), none
    # can count
    gx = ax + t * ex - ox
    gy = ay + t * ey - oy
    if gx * gx + gy * gy > (reach + 1e-9) * (reach + 1e-9):
        return
    period = 2.0 * math.pi / step
    u0 = (math.atan2(ay - oy, ax - ox) - base) / step
    u1 = (math.atan2(by - oy, bx - ox) - base) / step
    u0 -= math.floor(u0 / period) * period
    u1 -= math.floor(u1 / period) * period
    lo = min(u0, u1)
    hi = max(u0, u1)
    eps = 1e-9
    if hi - lo <= 0.5 * period:
        _hit_rays(ox, oy, base, step, nrays, int(math.ceil(lo - eps)), int(math.floor(hi + eps)), ax, ay, bx, by,
                  best)
    else:  # the span crosses angle `base`: rays from hi up, and from 0 to lo
        _hit_rays(ox, oy, base, step, nrays, int(math.ceil(hi - eps)), nrays - 1, ax, ay, bx, by, best)
        _hit_rays(ox, oy, base, step, nrays, 0, int(math.floor(lo + eps)), ax, ay, bx, by, best)


@njit(cache=True, inline="always")
def _cast_box(ox, oy, base, step, nrays, reach, bx, by, cb, sb, length, width, best):
    """Cast the sides of an oriented rectangle (centre bx, by, turned by the angle whose cosine and sine are cb, sb)
    that face (ox, oy); range 0 from inside it. The caller has checked it is in reach (`_in_reach`)."""
    hl = 0.5 * length
    hw = 0.5 * width
    px = ox - bx
    py = oy - by
    if abs(cb * px + sb * py) <= hl and abs(-sb * px + cb * py) <= hw:
        best[:] = 0.0
        return
    # the sensor in the box's frame: only the sides that face it can hold a nearest hit (the box is convex)
    lu = cb * px + sb * py
    lv = -sb * px + cb * py
    gu = max(abs(lu) - hl, 0.0)
    gv = max(abs(lv) - hw, 0.0)
    if gu * gu + gv * gv > (reach + 1e-9) * (reach + 1e-9):  # every side is out of reach (a hair kept for rounding)
        return
    facing = (lv > hw, lu < -hl, lv < -hw, lu > hl)  # sides +y, -x, -y, +x, between corners q and q + 1
    cx = (hl, -hl, -hl, hl)
    cy = (hw, hw, -hw, -hw)
    for q in range(4):
        if not facing[q]:
            continue
        r = (q + 1) % 4
        _cast(ox, oy, base, step, nrays, reach, bx + cb * cx[q] - sb * cy[q], by + sb * cx[q] + cb * cy[q],
              bx + cb * cx[r] - sb * cy[r], by + sb * cx[r] + cb * cy[r], best)


@njit(cache=True, inline="always")
def _in_reach(ox, oy, bx, by, length, width, reach):
    """A rectangle (centre bx, by) can meet a ray from (ox, oy) within `reach`, whatever its yaw."""
    far = reach + 0.5 * (length + width)  # >= reach + the half diagonal
    return (ox - bx) * (ox - bx) + (oy - by) * (oy - by) <= far * far


@njit(cache=True, inline="always")
def _memo_turn(memo, m, yaw):
    """(cos, sin) of `yaw`, kept in column m of memo (yaw, cos, sin) while the same yaw comes again."""
    if yaw != memo[0, m]:
        memo[0, m] = yaw
        memo[1, m] = math.cos(yaw)
        memo[2, m] = math.sin(yaw)
    return memo[1, m], memo[2, m]


@njit(cache=True)
def scan(cars, pose_x, pose_y, pose_yaw, mount_x, first_angle, step, oxy, oyaw, osize, boxes, visible, walls, edges,
         grid, reach, out, seen):
    """Raw ranges (inf = nothing within `reach`) of cars `cars` into out[car, ray]; returns the number of hits.

    Ray k looks at first_angle + k·step from the car's heading. Car i sees its own objects at oxy[i] (K, 2),
    turned by oyaw[i] (K,), each osize (length, width); the rectangles [x, y, yaw, length, width] of boxes (M, 5)
    where visible[i, m]; with `walls` the road edges (E, 4) listed for the car's grid cell (grid = (cell_start,
    cell_edges, x0, y0, cell, nx, ny)). A car with nothing in reach casts no ray: seen[i] is False and out[i] is
    left as it was (every ray reads inf); otherwise seen[i] is True.
    """
    nrays = out.shape[1]
    olen = osize[0]
    owid = osize[1]
    hits = 0
    # cos and sin of the last yaw seen for each of the cars' objects: the objects of many cars stand alike
    memo = np.full((3, oxy.shape[1]), np.nan)
    for k in range(cars.shape[0]):
        i = cars[k]
        c = math.cos(pose_yaw[i])
        s = math.sin(pose_yaw[i])
        ox = pose_x[i] + c * mount_x
        oy = pose_y[i] + s * mount_x
        base = pose_yaw[i] + first_angle
        best = out[i]
        started = walls
        if walls:
            best[:] = np.inf
        for m in range(oxy.shape[1]):
            if _in_reach(ox, oy, oxy[i, m, 0], oxy[i, m, 1], olen, owid, reach):
                if not started:
                    best[:] = np.inf
                    started = True
                cb, sb = _memo_turn(memo, m, oyaw[i, m])
                _cast_box(ox, oy, base, step, nrays, reach, oxy[i, m, 0], oxy[i, m, 1], cb, sb, olen, owid, best)
        for m in range(boxes.shape[0]):
            if visible[i, m] and _in_reach(ox, oy, boxes[m, 0], boxes[m, 1], boxes[m, 3], boxes[m, 4], reach):
                if not started:
                    best[:] = np.inf
                    started = True
                _cast_box(ox, oy, base, step, nrays, reach, boxes[m, 0], boxes[m, 1], math.cos(boxes[m, 2]),
                          math.sin(boxes[m, 2]), boxes[m, 3], boxes[m, 4], best)
        seen[i] = started
        if walls:
            _cast_walls(ox, oy, base, step, nrays, reach, edges, grid, best)
        if started:
            hits += _keep_in_reach(best, reach)
    return hits


@njit(cache=True, inline="always")
def _cast_walls(ox, oy, base, step, nrays, reach, edges, grid, best):
    """Cast the road edges listed for the grid cell of (ox, oy)."""
    cell_start, cell_edges, gx0, gy0, gcell, gnx, gny = grid
    cx = min(max(int((ox - gx0) / gcell), 0), gnx - 1)
    cy = min(max(int((oy - gy0) / gcell), 0), gny - 1)
    for q in range(cell_start[cy * gnx + cx], cell_start[cy * gnx + cx + 1]):
        e = cell_edges[q]
        _cast(ox, oy, base, step, nrays, reach, edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3], best)


@njit(cache=True, inline="always")
def _keep_in_reach(best, reach):
    """Ranges beyond `reach` become inf (nothing hit); returns the number of hits left."""
    hits = 0
    for a in range(best.shape[0]):
        if best[a] > reach:
            best[a] = np.inf
        else:
            hits += 1
    return hits


@njit(cache=True)
def _finish(cars, raw, seen, noise, lo, hi, out):
    """out[car] = raw ranges plus the next noise draw where a ray hit (in scan order), clipped to [lo, hi]; hi where
    it hit nothing or the car saw nothing (`seen` False)."""
    q = 0
    for i in cars:
        if not seen[i]:
            out[i, :] = hi
            continue
        for a in range(raw.shape[1]):
            v = raw[i, a]
            if v < np.inf:
                v += noise[q]
                q += 1
                out[i, a] = min(max(v, lo), hi)
            else:
                out[i, a] = hi


def edge_grid(edges: np.ndarray, reach: float, cell: float = GRID_CELL_M):
    """For every `cell` square around the edges, the edges within `reach` of it (CSR lists), as `scan` takes them."""
    lo = np.minimum(edges[:, :2], edges[:, 2:]).min(axis=0) - reach - cell
    hi = np.maximum(edges[:, :2], edges[:, 2:]).max(axis=0) + reach + cell
    nx, ny = (np.ceil((hi - lo) / cell).astype(int) + 1).tolist()
    lists: list[list[int]] = [[] for _ in range(nx * ny)]
    for e, (ax, ay, bx, by) in enumerate(edges.tolist()):
        c0 = int((min(ax, bx) - reach - lo[0]) // cell)
        c1 = int((max(ax, bx) + reach - lo[0]) // cell)
        r0 = int((min(ay, by) - reach - lo[1]) // cell)
        r1 = int((max(ay, by) + reach - lo[1]) // cell)
        for r in range(max(r0, 0), min(r1, ny - 1) + 1):
            for c in range(max(c0, 0), min(c1, nx - 1) + 1):
                lists[r * nx + c].append(e)
    start = np.zeros(nx * ny + 1, dtype=np.int64)
    start[1:] = np.cumsum([len(x) for x in lists])
    flat = np.array([e for x in lists for e in x], dtype=np.int64)
    return start, flat, float(lo[0]), float(lo[1]), float(cell), int(nx), int(ny)


class Lidar:
    """Ranges of every car's lidar (see the module docstring)."""

    def __init__(self, sim, walls: bool = False, noise_sigma_m: float = NOISE_SIGMA_M,
                 max_range_m: float = MAX_RANGE_M):
        self.sim = sim
        self.walls = bool(walls)
        self.noise_sigma_m = float(noise_sigma_m)
        self.max_range_m = float(max_range_m)
        self.reach_m = self.max_range_m + NOISE_REACH_SIGMAS * self.noise_sigma_m
        self.angles = lidar_ray_angles()
        self.step = LIDAR_STEP_RAD
        self.mount_x = lidar_position()
        self.edges = np.ascontiguousarray(sim.track.road_edges, dtype=np.float64)
        # a cell lists every edge within reach of any point in it (cell diagonal added)
        self.grid = edge_grid(self.edges, self.reach_m + GRID_CELL_M * math.sqrt(2.0)) if self.walls \
            else (np.zeros(2, dtype=np.int64), np.zeros(0, dtype=np.int64), 0.0, 0.0, 1.0, 1, 1)
        self.set_objects(None)
        objects = getattr(sim, "objects", None)
        self._objects = objects if objects is not None and objects.num_objects else None
        # each car's objects are read from the ObjectSet's arrays at every scan; their model's size is fixed
        self._osize = np.array(objects.box_size_m if self._objects is not None else (0.0, 0.0), dtype=np.float64)
        self._no_objects = (np.zeros((sim.num_cars, 0, 2)), np.zeros((sim.num_cars, 0)))
        self.raw = np.full((sim.num_cars, LIDAR_RAYS), np.inf)
        self._seen = np.zeros(sim.num_cars, dtype=np.bool_)
        self.ranges = np.full((sim.num_cars, LIDAR_RAYS), self.max_range_m, dtype=np.float32)
        self._all = np.arange(sim.num_cars, dtype=np.int64)

    def set_objects(self, boxes, visible=None) -> None:
        """Rectangles the rays hit: (M, 5) [x, y, yaw_rad, length_m, width_m] in the world frame, or None.

        `visible` (num_cars, M) bool says which car sees which box (default: every car sees all).
        Call again whenever the objects move.
        """
        b = np.zeros((0, 5)) if boxes is None else np.asarray(boxes, dtype=np.float64).reshape(-1, 5)
        n = self.sim.num_cars
        v = np.ones((n, b.shape[0]), dtype=np.bool_) if visible is None else np.asarray(visible, dtype=np.bool_)
        if v.shape != (n, b.shape[0]):
            raise ValueError(f"visible must have shape {(n, b.shape[0])}, got {v.shape}")
        self.boxes = np.ascontiguousarray(b)
        self.visible = np.ascontiguousarray(v)

    def scan(self, rows=None) -> np.ndarray:
        """Measure cars `rows` (all by default) into `self.ranges` (B, 64) float32, m, and return it (not a copy).

        Ranges are clipped to [0.15, max_range_m]; a ray that hits nothing reads max_range_m.
        """
        idx = self._all if rows is None else np.ascontiguousarray(rows, dtype=np.int64)
        # objects move at every reset (and bot cars at every step): read where they stand now
        oxy, oyaw = (self._objects.xy, self._objects.yaw) if self._objects is not None else self._no_objects
        if oxy.shape[1] or self.boxes.shape[0] or self.walls:
            car = self.sim.car
            hits = scan(idx, car[:, K.CX], car[:, K.CY], car[:, K.CYAW], self.mount_x,
                        LIDAR_MIN_ANGLE_RAD + LIDAR_YAW_RAD, self.step, oxy, oyaw, self._osize, self.boxes,
                        self.visible, self.walls, self.edges, self.grid, self.reach_m, self.raw, self._seen)
            noise = self.sim.rng.normal(0.0, self.noise_sigma_m, size=hits) if self.noise_sigma_m > 0.0 and hits \
                else np.zeros(hits)
            _finish(idx, self.raw, self._seen, noise, MIN_RANGE_M, self.max_range_m, self.ranges)
        return self.ranges


def sectors(ranges: np.ndarray) -> np.ndarray:
    """(B, 8) float32: 1 where a sector's smallest range is below 0.5 m (AWS's binary sector filter)."""
    r = ranges.reshape(ranges.shape[0], SECTORS, -1)
    return (r.min(axis=2) < SECTOR_CLIP_M).astype(np.float32)


def discretized_sectors(ranges: np.ndarray, num_sectors: int, num_values: int, clipping_dist: float) -> np.ndarray:
    """(B, num_sectors * num_values) float32 one-hot bins of each sector's smallest range (AWS's
    ObservationSectorDiscretizeFilter): bin floor(min(r, clip) / (clip / num_values)); the bin at
    `clip` itself (nothing seen) is dropped, so such a sector reads all zeros."""
    b = ranges.shape[0]
    m = np.minimum(ranges.reshape(b, num_sectors, -1).min(axis=2), clipping_dist)
    idx = np.floor(m / (clipping_dist / num_values)).astype(np.int64)
    out = np.zeros((b, num_sectors, num_values + 1), dtype=np.float32)
    np.put_along_axis(out, np.minimum(idx, num_values)[..., None], 1.0, axis=2)
    return out[:, :, :num_values].reshape(b, num_sectors * num_values)


def discretized_config(lidar_config: dict | None, source: str = "model_metadata.json") -> tuple[int, int, float]:
    """(num_sectors, num_values_per_sector, clipping_dist) from a model's `lidar_config`, AWS defaults
    for missing keys; clipping_dist is clamped to the sensor's range as AWS does."""
    cfg = dict(DISCRETIZED_DEFAULTS)
    given = dict(lidar_config or {})
    unknown = sorted(set(given) - set(cfg))
    if unknown:
        raise ConfigError(f"{source}: lidar_config has unknown key {unknown[0]!r}; allowed: {', '.join(cfg)}")
    cfg.update(given)
    n, v, clip = cfg["num_sectors"], cfg["num_values_per_sector"], cfg["clipping_dist"]
    for key in ("num_sectors", "num_values_per_sector"):
        if isinstance(cfg[key], bool) or not isinstance(cfg[key], int) or cfg[key] < 1:
            raise ConfigError(f"{source}: lidar_config.{key} must be a whole number >= 1, got {cfg[key]!r}")
    if LIDAR_RAYS % n:
        raise ConfigError(f"{source}: lidar_config.num_sectors must divide the {LIDAR_RAYS} lidar rays, got {n}")
    if isinstance(clip, bool) or not isinstance(clip, int | float) or not math.isfinite(clip):
        raise ConfigError(f"{source}: lidar_config.clipping_dist must be a number of metres, got {clip!r}")
    return n, v, float(min(max(clip, GAZEBO_RANGE_M[0]), GAZEBO_RANGE_M[1]))


class LidarObservation:
    """`lidar` (64,) float32 ranges in [0.15, 1.0] m, `sector_lidar` (8,) float32 in {0, 1}, or
    `discretized_sector_lidar` (num_sectors * num_values_per_sector,) float32 one-hot bins."""

    partial_update = True
    KINDS = ("lidar", "sector_lidar", "discretized_sector_lidar")

    def __init__(self, sim, sector: bool = False, walls: bool = False, kind: str | None = None,
                 lidar_config: dict | None = None, source: str = "model_metadata.json"):
        kind = kind or ("sector_lidar" if sector else "lidar")
        if kind not in self.KINDS:
            raise ValueError(f"LidarObservation kind must be one of {self.KINDS}, got {kind!r}")
        self.name = kind
        self.sector = kind == "sector_lidar"
        self.discretized = discretized_config(lidar_config, source) if kind == "discretized_sector_lidar" else None
        reach = self.discretized[2] if self.discretized else MAX_RANGE_M
        self.lidar = Lidar(sim, walls=walls, max_range_m=reach)

    @property
    def space(self) -> gym.Space:
        if self.discretized:
            n, v, _ = self.discretized
            return gym.spaces.Box(0.0, 1.0, shape=(n * v,), dtype=np.float32)
        if self.sector:
            return gym.spaces.Box(0.0, 1.0, shape=(SECTORS,), dtype=np.float32)
        return gym.spaces.Box(MIN_RANGE_M, MAX_RANGE_M, shape=(LIDAR_RAYS,), dtype=np.float32)

    def __call__(self, rows=None) -> np.ndarray:
        r = self.lidar.scan(rows)
        if self.discretized:
            return discretized_sectors(r, *self.discretized)
        return sectors(r) if self.sector else r.copy()
