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
ATAN2_ERROR_RAD = 1e-5  # the most the quick atan2 that picks a segment's rays may be off
SECTORS = 8
SECTOR_CLIP_M = 0.5
NOISE_REACH_SIGMAS = 6  # a hit further than max range + 6 σ reads max range whatever the noise
GRID_CELL_M = 0.25
GAZEBO_RANGE_M = (0.15, 12.0)  # the simulated sensor's own range (facts §4)
# AWS DiscretizedSectorLidarDefaults (boto/s3/constants.py)
DISCRETIZED_DEFAULTS = {"num_sectors": 8, "num_values_per_sector": 8, "clipping_dist": 2.0}


@njit(cache=True, inline="always")
def _atan2(y, x):
    """atan2(y, x) within ATAN2_ERROR_RAD, without a library call: an odd polynomial on [0, 1] and the octant
    folded back. It only picks the rays a segment can meet; every pick is then tested exactly."""
    ax = abs(x)
    ay = abs(y)
    if ay <= ax:
        if ax == 0.0:
            return 0.0
        z = ay / ax
    else:
        z = ax / ay
    z2 = z * z
    a = z * (0.99997726 + z2 * (-0.33262347 + z2 * (0.19354346 + z2 * (-0.11643287 + z2 * (0.05265332
                                                                                          - 0.01172120 * z2)))))
    if ay > ax:
        a = 0.5 * math.pi - a
    if x < 0.0:
        a = math.pi - a
    return -a if y < 0.0 else a


@njit(cache=True, inline="always")
def _hit_rays(dirs, lo, hi, ax, ay, bx, by, best):
    """Intersect rays lo..hi (indices, clipped to the scan; ray k along the unit dirs[k] from the origin) with
    segment a-b, both in the scan frame; keep the nearer hits in best. The ray meets the segment at distance
    t = tn / den and at share u = un / den along it: a hit where t >= 0 and u is in [0, 1] (a hair either side),
    tested without dividing; one division for a hit."""
    ex = bx - ax
    ey = by - ay
    tn = ax * ey - ay * ex
    for k in range(max(lo, 0), min(hi, dirs.shape[0] - 1) + 1):
        den = dirs[k, 0] * ey - dirs[k, 1] * ex
        un = ax * dirs[k, 1] - ay * dirs[k, 0]
        if den >= 1e-15:
            hit = tn >= 0.0 and -1e-12 * den <= un <= (1.0 + 1e-12) * den
        elif den <= -1e-15:
            hit = tn <= 0.0 and -1e-12 * den >= un >= (1.0 + 1e-12) * den
        else:  # (parallel)
            hit = False
        if hit:
            t = tn / den
            if t < best[k]:
                best[k] = t


@njit(cache=True, inline="always")
def _cast(dirs, per_rad, reach, ax, ay, bx, by, best):
    """Cast segment a-b, in the scan frame (origin the lidar, ray k at angle k / per_rad), onto the rays it can
    meet: those within the angle it spans, a little slack kept for the quick angles. A segment further than
    `reach` is skipped."""
    ex = bx - ax
    ey = by - ay
    ll = ex * ex + ey * ey
    t = min(max(-(ax * ex + ay * ey) / ll, 0.0), 1.0) if ll > 0.0 else 0.0
    # every hit is at least as far as the segment's nearest point: beyond reach (a hair kept for rounding), none
    # can count
    gx = ax + t * ex
    gy = ay + t * ey
    # (no early returns in these inlined helpers: numba compiles them into much slower loops)
    if gx * gx + gy * gy <= (reach + 1e-9) * (reach + 1e-9):
        period = 2.0 * math.pi * per_rad
        u0 = _atan2(ay, ax) * per_rad  # in (-period / 2, period / 2]
        u1 = _atan2(by, bx) * per_rad
        u0 = u0 + period if u0 < 0.0 else u0
        u1 = u1 + period if u1 < 0.0 else u1
        lo = min(u0, u1)
        hi = max(u0, u1)
        slack = ATAN2_ERROR_RAD * 4.0 * per_rad
        if abs(hi - lo - 0.5 * period) <= slack:  # seen edge on, from (nearly) on its line: too close to call
            _hit_rays(dirs, 0, dirs.shape[0] - 1, ax, ay, bx, by, best)
        elif hi - lo < 0.5 * period:
            _hit_span(dirs, period, lo - slack, hi + slack, ax, ay, bx, by, best)
        else:  # the span crosses angle 0: from hi round to lo
            _hit_span(dirs, period, hi - slack, lo + period + slack, ax, ay, bx, by, best)


@njit(cache=True, inline="always")
def _hit_span(dirs, period, a, b, ax, ay, bx, by, best):
    """`_hit_rays` for the rays at angles a..b (ray units, a full turn being `period`; a may be below 0 and b
    past a full turn: those parts wrap round)."""
    _hit_rays(dirs, int(math.ceil(a)), int(math.floor(b)), ax, ay, bx, by, best)
    if a < 0.0:
        _hit_rays(dirs, int(math.ceil(a + period)), dirs.shape[0] - 1, ax, ay, bx, by, best)
    if b >= period:
        _hit_rays(dirs, 0, int(math.floor(b - period)), ax, ay, bx, by, best)


@njit(cache=True, inline="always")
def _cast_box(dirs, per_rad, reach, bx, by, cb, sb, length, width, best):
    """Cast the sides that face the lidar of an oriented rectangle (centre bx, by in the scan frame, turned by the
    angle whose cosine and sine are cb, sb); range 0 from inside it."""
    hl = 0.5 * length
    hw = 0.5 * width
    # the lidar in the box's frame: only the sides that face it can hold a nearest hit (the box is convex)
    lu = -(cb * bx + sb * by)
    lv = sb * bx - cb * by
    gu = max(abs(lu) - hl, 0.0)
    gv = max(abs(lv) - hw, 0.0)
    if abs(lu) <= hl and abs(lv) <= hw:
        best[:] = 0.0
    elif gu * gu + gv * gv <= (reach + 1e-9) * (reach + 1e-9):  # else every side is out of reach (a hair kept)
        facing = (lv > hw, lu < -hl, lv < -hw, lu > hl)  # sides +y, -x, -y, +x, between corners q and q + 1
        cx = (hl, -hl, -hl, hl)
        cy = (hw, hw, -hw, -hw)
        for q in range(4):
            if facing[q]:
                r = (q + 1) % 4
                _cast(dirs, per_rad, reach, bx + cb * cx[q] - sb * cy[q], by + sb * cx[q] + cb * cy[q],
                      bx + cb * cx[r] - sb * cy[r], by + sb * cx[r] + cb * cy[r], best)


@njit(cache=True, inline="always")
def _near(dx, dy, length, width, reach):
    """A rectangle (centre dx, dy from the lidar) can meet a ray within `reach`, whatever its yaw."""
    far = reach + 0.5 * (length + width)  # >= reach + the half diagonal
    return dx * dx + dy * dy <= far * far


@njit(cache=True, inline="always")
def _memo_turn(memo, m, yaw):
    """(cos, sin) of `yaw`, kept in column m of memo (yaw, cos, sin) while the same yaw comes again."""
    if yaw != memo[0, m]:
        memo[0, m] = yaw
        memo[1, m] = math.cos(yaw)
        memo[2, m] = math.sin(yaw)
    return memo[1, m], memo[2, m]


@njit(cache=True, inline="always")
def _anything_near(i, px, py, slack, oxy, olen, owid, boxes, visible, reach):
    """Car i (base at px, py; its lidar within `slack` of it) may have one of its objects or `boxes` in reach."""
    found = False
    for m in range(oxy.shape[1]):
        found |= _near(oxy[i, m, 0] - px, oxy[i, m, 1] - py, olen, owid, reach + slack)
    for m in range(boxes.shape[0]):
        found |= visible[i, m] and _near(boxes[m, 0] - px, boxes[m, 1] - py, boxes[m, 3], boxes[m, 4], reach + slack)
    return found


# error_model="numpy": no zero-division checks in the loops (every division here has a non-zero divisor), ~12 %
# faster
@njit(cache=True, error_model="numpy")
def scan(cars, car, mount_x, first_angle, dirs, per_rad, oxy, oyaw, osize, boxes, visible, walls, edges, grid, reach,
         lo, hi, best, hit_at, hit_raw, ranges):
    """Ranges of cars `cars` without noise into ranges[car, ray]: the raw range clipped to [lo, hi] where a ray hits
    something within `reach`, else hi. Returns the number of hits, listed in scan order in hit_at (car * rays +
    ray) and hit_raw (the raw range), for `add_noise`.

    The cars' base poses are car[:, K.CX], [K.CY], [K.CYAW]; ray k looks along dirs[k] (unit, at angle k / per_rad)
    from first_angle off the heading. Car i sees its own objects at oxy[i] (K, 2), turned by oyaw[i] (K,), each
    osize (length, width); the rectangles [x, y, yaw, length, width] of boxes (M, 5) where visible[i, m]; with
    `walls` the road edges (E, 4) listed for the car's grid cell (grid = (cell_start, cell_edges, x0, y0, cell, nx,
    ny)). `best` is scratch for one car's rays.
    """
    olen = osize[0]
    owid = osize[1]
    cf = math.cos(first_angle)
    sf = math.sin(first_angle)
    nrays = dirs.shape[0]
    hits = 0
    # cos and sin of the last yaw seen for each of the cars' objects: the objects of many cars stand alike
    memo = np.full((3, oxy.shape[1]), np.nan)
    for k in range(cars.shape[0]):
        i = cars[k]
        px = car[i, K.CX]
        py = car[i, K.CY]
        if not walls and not _anything_near(i, px, py, abs(mount_x), oxy, olen, owid, boxes, visible, reach):
            ranges[i, :] = hi  # (most cars: no trigonometry for them)
            continue
        c = math.cos(car[i, K.CYAW])
        s = math.sin(car[i, K.CYAW])
        ox = px + c * mount_x
        oy = py + s * mount_x
        # the scan frame: origin the lidar, x along ray 0 (first_angle off the heading)
        cs = c * cf - s * sf
        ss = s * cf + c * sf
        best[:] = np.inf
        for m in range(oxy.shape[1]):
            dx = oxy[i, m, 0] - ox
            dy = oxy[i, m, 1] - oy
            if _near(dx, dy, olen, owid, reach):
                co, so = _memo_turn(memo, m, oyaw[i, m])
                _cast_box(dirs, per_rad, reach, cs * dx + ss * dy, cs * dy - ss * dx, co * cs + so * ss,
                          so * cs - co * ss, olen, owid, best)
        for m in range(boxes.shape[0]):
            dx = boxes[m, 0] - ox
            dy = boxes[m, 1] - oy
            if visible[i, m] and _near(dx, dy, boxes[m, 3], boxes[m, 4], reach):
                co = math.cos(boxes[m, 2])
                so = math.sin(boxes[m, 2])
                _cast_box(dirs, per_rad, reach, cs * dx + ss * dy, cs * dy - ss * dx, co * cs + so * ss,
                          so * cs - co * ss, boxes[m, 3], boxes[m, 4], best)
        if walls:
            _cast_walls(ox, oy, cs, ss, dirs, per_rad, reach, edges, grid, best)
        for a in range(nrays):
            v = best[a]
            if v > reach:
                ranges[i, a] = hi
            else:
                ranges[i, a] = min(max(v, lo), hi)
                hit_at[hits] = i * nrays + a
                hit_raw[hits] = v
                hits += 1
    return hits


@njit(cache=True, error_model="numpy")
def add_noise(hit_at, hit_raw, z, sigma, lo, hi, ranges):
    """ranges at the hits `scan` listed: the raw range plus sigma times the next standard normal draw z[q] (what
    `Generator.normal(0, sigma)` draws, to the bit), clipped to [lo, hi]."""
    nrays = ranges.shape[1]
    for q in range(z.shape[0]):
        ranges[hit_at[q] // nrays, hit_at[q] % nrays] = min(max(hit_raw[q] + sigma * z[q], lo), hi)


@njit(cache=True, inline="always")
def _cast_walls(ox, oy, cs, ss, dirs, per_rad, reach, edges, grid, best):
    """Cast the road edges listed for the grid cell of the lidar at (ox, oy), the scan frame turned by the angle
    whose cosine and sine are cs, ss."""
    cell_start, cell_edges, gx0, gy0, gcell, gnx, gny = grid
    cx = min(max(int((ox - gx0) / gcell), 0), gnx - 1)
    cy = min(max(int((oy - gy0) / gcell), 0), gny - 1)
    for q in range(cell_start[cy * gnx + cx], cell_start[cy * gnx + cx + 1]):
        e = cell_edges[q]
        ax = edges[e, 0] - ox
        ay = edges[e, 1] - oy
        bx = edges[e, 2] - ox
        by = edges[e, 3] - oy
        _cast(dirs, per_rad, reach, cs * ax + ss * ay, cs * ay - ss * ax, cs * bx + ss * by, cs * by - ss * bx, best)


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
        k = np.arange(LIDAR_RAYS) * self.step
        self._dirs = np.ascontiguousarray(np.column_stack([np.cos(k), np.sin(k)]))  # in the scan frame
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
        self._best = np.empty(LIDAR_RAYS)
        self._hit_at = np.empty(sim.num_cars * LIDAR_RAYS, dtype=np.int64)
        self._hit_raw = np.empty(sim.num_cars * LIDAR_RAYS)
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
            lo, hi = MIN_RANGE_M, self.max_range_m
            if self._hit_at.size < idx.size * LIDAR_RAYS:  # (rows listed more than once)
                self._hit_at = np.empty(idx.size * LIDAR_RAYS, dtype=np.int64)
                self._hit_raw = np.empty(idx.size * LIDAR_RAYS)
            hits = scan(idx, self.sim.car, self.mount_x, LIDAR_MIN_ANGLE_RAD + LIDAR_YAW_RAD, self._dirs,
                        1.0 / self.step, oxy, oyaw, self._osize, self.boxes, self.visible, self.walls, self.edges,
                        self.grid, self.reach_m, lo, hi, self._best, self._hit_at, self._hit_raw, self.ranges)
            if self.noise_sigma_m > 0.0 and hits:
                add_noise(self._hit_at, self._hit_raw, self.sim.rng.standard_normal(hits), self.noise_sigma_m, lo, hi,
                          self.ranges)
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
