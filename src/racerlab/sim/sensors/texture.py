"""The track as the camera renderer samples it: a greyscale raster with a mip pyramid, built once per track.

Two stages. `TrackTexture` is a 2 cm raster of *distances*: each cell holds, for its centre
point, the arc length `s` and signed offset `d` (+ left) of the nearest centre-line point, the
index of that centre segment, and the signed distance `e` to the nearest road border (+ on the
road). Within a cell these vary linearly (moving from the cell centre along the segment's
direction), so the paint (border lines, dashed centre line) is known exactly at any point.

`TrackRaster` evaluates that paint over every 1 cm texel (the fraction of the texel each paint
covers, so the raster itself is anti-aliased) and stores the grey under white light, plus, for
domain randomization, the fractions of ground and centre paint, whose grey depends on the light
colour. Coarser levels (2, 4, ... cm) average 2×2 texels; the renderer picks per image row the
level that matches the pixel's footprint on the ground, which is what keeps distant lines from
shimmering.

A grainy look (`TrackLook.grain_*`) also puts its grain into the raster: blotches (noise on a 3 cm grid,
interpolated) and texel noise, each a fraction of the material's grey, seeded by the look, so that the grain
is fixed to the ground and the same on every run. The grain finer than a texel is a separate small tile
(`fine_grain`) that the renderer adds on the nearest rows.
"""

from __future__ import annotations

import math
import weakref

import numpy as np
from numba import njit

from racerlab.sim.sensors.look import CENTER, GROUND, LINE, ROAD, TrackLook
from racerlab.track import Track

CELL_M = 0.02  # distance raster
RASTER_CELL_M = 0.005  # paint raster, level 0
BORDER_REACH_M = 0.25  # |e| is exact up to this distance from a border, clamped beyond
FAR_M = 10.0  # `d` of cells no centre segment reached
MAX_LEVELS = 9  # 5 mm ... 1.28 m
BLOTCH_TEXELS = 6  # the grain's blotches: noise on a 3 cm grid
COARSE_SHARE = 0.5  # the texel noise's share of the fine grain (a 5 mm texel averages the finer grain)
FINE_CELL_M = RASTER_CELL_M / 4  # the fine grain tile: 1.25 mm per value, 256 values (0.32 m) before it repeats
FINE_TILE = 256  # 64 KB of int8: it stays in the core's cache while a frame reads it all over
FINE_SCALE = 1.0 / 32.0  # the tile's int8 values are unit noise × 32


@njit(cache=True, inline="always")
def _band(lo, hi, x, half):
    """Fraction of [x - half, x + half] inside [lo, hi]."""
    a = max(lo, x - half)
    b = min(hi, x + half)
    return min(max((b - a) / (2.0 * half), 0.0), 1.0)


@njit(cache=True, inline="always")
def _dash_integral(x, period, on):
    k = math.floor(x / period)
    return k * on + min(x - k * period, on)


@njit(cache=True)
def _paint_texels(rec, normals, x0, y0, cell, tcell, paint, out):
    """Fractions of road, line and centre paint over each `tcell` texel of `out` (h, w, 3).

    paint = [line width, centre width, dash period, dash length]. A texel's footprint is a
    `tcell` square; each paint band is integrated over it across (n) and along (t) the centre line.
    """
    h, w = out.shape[0], out.shape[1]
    rh, rw = rec.shape[0], rec.shape[1]
    inv = 1.0 / cell
    for r in range(h):
        wy = y0 + (r + 0.5) * tcell
        for c in range(w):
            wx = x0 + (c + 0.5) * tcell
            ix = min(int((wx - x0) * inv), rw - 1)
            iy = min(int((wy - y0) * inv), rh - 1)
            ddx = wx - (x0 + (ix + 0.5) * cell)
            ddy = wy - (y0 + (iy + 0.5) * cell)
            seg = int(rec[iy, ix, 3])
            nx = normals[seg, 0]
            ny = normals[seg, 1]
            dn = nx * ddx + ny * ddy
            d0 = rec[iy, ix, 1]
            d = d0 + dn
            sd = rec[iy, ix, 0] + ny * ddx - nx * ddy
            e = rec[iy, ix, 2] - dn if d0 >= 0.0 else rec[iy, ix, 2] + dn
            half = 0.5 * tcell * (abs(nx) + abs(ny)) + 1e-9
            road = _band(0.0, 1e9, e, half)
            line = _band(0.0, paint[0], e, half)
            period = paint[2]
            on = paint[3]
            dash = (_dash_integral(sd + half, period, on) - _dash_integral(sd - half, period, on)) / (2.0 * half)
            cen = min(_band(-0.5 * paint[1], 0.5 * paint[1], d, half) * dash, max(road - line, 0.0))
            out[r, c, 0] = road
            out[r, c, 1] = line
            out[r, c, 2] = cen


@njit(cache=True, inline="always")
def _cell_window(ax, ay, dx, dy, reach, x0, y0, cell, h, w):
    """Row and column ranges [r0, r1) x [c0, c1) of the grid cells within `reach` of a segment's box."""
    c0 = max(int((min(ax, ax + dx) - reach - x0) / cell), 0)
    c1 = min(int((max(ax, ax + dx) + reach - x0) / cell) + 1, w)
    r0 = max(int((min(ay, ay + dy) - reach - y0) / cell), 0)
    r1 = min(int((max(ay, ay + dy) + reach - y0) / cell) + 1, h)
    return r0, r1, c0, c1


@njit(cache=True)
def _splat_center(center, cum_s, x0, y0, cell, reach, rec, best):
    """For every cell within `reach` of a centre segment keep the nearest segment's s, d and index."""
    h, w = best.shape
    for i in range(center.shape[0] - 1):
        ax, ay = center[i, 0], center[i, 1]
        dx, dy = center[i + 1, 0] - ax, center[i + 1, 1] - ay
        ll = dx * dx + dy * dy
        if ll <= 0.0:
            continue
        seg_len = math.sqrt(ll)
        r0, r1, c0, c1 = _cell_window(ax, ay, dx, dy, reach, x0, y0, cell, h, w)
        for r in range(r0, r1):
            py = y0 + (r + 0.5) * cell
            for c in range(c0, c1):
                px = x0 + (c + 0.5) * cell
                t = ((px - ax) * dx + (py - ay) * dy) / ll
                t = min(max(t, 0.0), 1.0)
                qx, qy = px - ax - t * dx, py - ay - t * dy
                d2 = qx * qx + qy * qy
                if d2 < best[r, c]:
                    best[r, c] = d2
                    cross = dx * (py - ay) - dy * (px - ax)
                    rec[r, c, 0] = cum_s[i] + t * seg_len
                    rec[r, c, 1] = math.sqrt(d2) if cross >= 0.0 else -math.sqrt(d2)
                    rec[r, c, 3] = i


@njit(cache=True)
def _splat_edges(edges, x0, y0, cell, reach, best):
    """Squared distance of every cell within `reach` to the nearest border edge."""
    h, w = best.shape
    for i in range(edges.shape[0]):
        ax, ay = edges[i, 0], edges[i, 1]
        dx, dy = edges[i, 2] - ax, edges[i, 3] - ay
        ll = max(dx * dx + dy * dy, 1e-18)
        r0, r1, c0, c1 = _cell_window(ax, ay, dx, dy, reach, x0, y0, cell, h, w)
        for r in range(r0, r1):
            py = y0 + (r + 0.5) * cell
            for c in range(c0, c1):
                px = x0 + (c + 0.5) * cell
                t = min(max(((px - ax) * dx + (py - ay) * dy) / ll, 0.0), 1.0)
                qx, qy = px - ax - t * dx, py - ay - t * dy
                d2 = qx * qx + qy * qy
                if d2 < best[r, c]:
                    best[r, c] = d2


class TrackTexture:
    """The sampled description of one track's paint (see the module docstring)."""

    def __init__(self, track: Track, look: TrackLook | None = None, cell_m: float = CELL_M, margin_m: float = 1.0):
        self.look = look or TrackLook()
        self.cell = float(cell_m)
        pts = np.vstack([track.inner, track.outer, track.center])
        lo = pts.min(axis=0) - margin_m
        hi = pts.max(axis=0) + margin_m
        self.x0, self.y0 = float(lo[0]), float(lo[1])
        self.w = int(math.ceil((hi[0] - lo[0]) / self.cell))
        self.h = int(math.ceil((hi[1] - lo[1]) / self.cell))
        rec = np.zeros((self.h, self.w, 4), dtype=np.float32)
        rec[:, :, 1] = FAR_M
        best = np.full((self.h, self.w), np.inf)
        reach_c = 0.5 * float(track.widths.max()) + BORDER_REACH_M + 2 * self.cell
        _splat_center(np.ascontiguousarray(track.center), track.waypoint_s, self.x0, self.y0, self.cell, reach_c,
                      rec, best)
        self._set_border_distance(track, rec)
        self.rec = rec
        d = np.diff(track.center, axis=0)
        n = np.hypot(d[:, 0], d[:, 1])[:, None]
        self.normals = np.ascontiguousarray(np.stack([-d[:, 1], d[:, 0]], axis=1) / np.maximum(n, 1e-12))
        self.dash_period, self.dash_on = self._dashes(track)

    def _set_border_distance(self, track: Track, rec: np.ndarray) -> None:
        best = np.full((self.h, self.w), BORDER_REACH_M ** 2)
        _splat_edges(track.road_edges, self.x0, self.y0, self.cell, BORDER_REACH_M + 2 * self.cell, best)
        near = np.abs(rec[:, :, 1]) < FAR_M
        rows, cols = np.nonzero(near)
        centres = np.stack([self.x0 + (cols + 0.5) * self.cell, self.y0 + (rows + 0.5) * self.cell], axis=1)
        inside = np.zeros((self.h, self.w), dtype=bool)
        inside[rows, cols] = track.contains(centres)
        rec[:, :, 2] = np.where(inside, 1.0, -1.0) * np.sqrt(best)

    def _dashes(self, track: Track) -> tuple[float, float]:
        look = self.look
        period = look.dash_m + look.gap_m
        if track.closed:
            # a whole number of dashes per lap, so the pattern does not jump at waypoint 0
            period = track.length / max(1, round(track.length / period))
        return period, period * look.dash_m / (look.dash_m + look.gap_m)


def _halve(a: np.ndarray) -> np.ndarray:
    """2×2 mean of a (h, w) float array, its last row / column repeated when odd."""
    h, w = a.shape
    a = np.pad(a, ((0, h % 2), (0, w % 2)), mode="edge")
    return 0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2])


class Pyramid:
    """Mip levels of one uint8 channel in one flat array, each level padded by a repeated last row and
    column so that a bilinear read at (ix + 1, iy + 1) never leaves it.

    `off[L]` is the level's first element, `stride[L]` its padded width, `w[L]`, `h[L]` its size.
    """

    def __init__(self, levels: list[np.ndarray]):
        parts = []
        self.off = np.zeros(len(levels), dtype=np.int64)
        self.stride = np.zeros(len(levels), dtype=np.int64)
        self.w = np.zeros(len(levels), dtype=np.int64)
        self.h = np.zeros(len(levels), dtype=np.int64)
        pos = 0
        for k, lv in enumerate(levels):
            q = np.pad(np.clip(np.rint(lv), 0, 255).astype(np.uint8), ((0, 1), (0, 1)), mode="edge")
            self.off[k] = pos
            self.stride[k] = q.shape[1]
            self.h[k], self.w[k] = lv.shape
            parts.append(q.ravel())
            pos += q.size
        self.data = np.concatenate(parts)

    def level(self, k: int) -> np.ndarray:
        """Level k as an (h, w) uint8 view (without the padding)."""
        n = (self.h[k] + 1) * self.stride[k]
        return self.data[self.off[k]:self.off[k] + n].reshape(self.h[k] + 1, self.stride[k])[:-1, :-1]


def _levels(a: np.ndarray, count: int) -> list[np.ndarray]:
    out = [a]
    while len(out) < count and min(out[-1].shape) > 2:
        out.append(_halve(out[-1]))
    return out


class TrackRaster:
    """Grey and paint-fraction pyramids of one track (see the module docstring).

    `grey` holds the grey under white light (0-255); `ground` and `center` the fractions of ground
    and centre paint (0-255 for 0-1), built on first use (only domain randomization needs them).
    Texel (i, j) of level L covers x0 + [j, j+1) · cell · 2^L, y0 + [i, i+1) · cell · 2^L.
    """

    def __init__(self, track: Track, look: TrackLook | None = None, cell_m: float = RASTER_CELL_M):
        self.look = look or TrackLook()
        tex = TrackTexture(track, self.look)
        self.cell = float(cell_m)
        self.x0, self.y0 = tex.x0, tex.y0
        w = int(math.ceil(tex.w * tex.cell / self.cell))
        h = int(math.ceil(tex.h * tex.cell / self.cell))
        paint = np.array([self.look.line_width_m, self.look.center_width_m, tex.dash_period, tex.dash_on])
        frac = np.empty((h, w, 3), dtype=np.float32)
        _paint_texels(tex.rec, tex.normals, tex.x0, tex.y0, tex.cell, self.cell, paint, frac)
        g = self.look.grey()
        road, line, cen = frac[..., 0], frac[..., 1], frac[..., 2]
        bare = np.maximum(road - line - cen, 0.0)
        look = self.look
        # grey = sum over materials of share · grey · (1 + blotch · B + texel noise · N): three weighted sums
        parts = ((GROUND, 1.0 - road, 3), (ROAD, bare, 0), (LINE, line, 1), (CENTER, cen, 2))
        grey = np.zeros((h, w), dtype=np.float32)
        blotchy = np.zeros((h, w), dtype=np.float32) if look.grainy else None
        noisy = np.zeros((h, w), dtype=np.float32) if look.grainy else None
        for m, share, k in parts:
            grey += np.float32(g[m]) * share
            if look.grainy:
                blotchy += np.float32(g[m] * look.grain_blotch[k]) * share
                noisy += np.float32(g[m] * COARSE_SHARE * look.grain_fine[k]) * share
        if look.grainy:
            blotch, texel = coarse_grain(h, w, look)
            grey += blotchy * blotch + noisy * texel
        # kept as bytes until domain randomization asks for their pyramids
        self._ground0 = np.rint(255.0 * (1.0 - road)).astype(np.uint8)
        self._center0 = np.rint(255.0 * cen).astype(np.uint8)
        self.grey = Pyramid(_levels(grey.astype(np.float64), MAX_LEVELS))
        self._fractions: tuple[Pyramid, Pyramid] | None = None

    @property
    def num_levels(self) -> int:
        return len(self.grey.off)

    @property
    def level_inv_cell(self) -> np.ndarray:
        return 1.0 / (self.cell * 2.0 ** np.arange(self.num_levels))

    def fractions(self) -> tuple[Pyramid, Pyramid]:
        """(ground, centre) paint-fraction pyramids, with the grey pyramid's layout."""
        if self._fractions is None:
            n = self.num_levels
            self._fractions = (Pyramid(_levels(self._ground0.astype(np.float64), n)),
                               Pyramid(_levels(self._center0.astype(np.float64), n)))
        return self._fractions

    @property
    def nbytes(self) -> int:
        extra = sum(p.data.nbytes for p in self._fractions) if self._fractions else 0
        return int(self.grey.data.nbytes + extra)


def coarse_grain(h: int, w: int, look: TrackLook) -> tuple[np.ndarray, np.ndarray]:
    """Two (h, w) float32 fields of unit standard deviation over the raster's texels: blotches (noise on a grid of
    BLOTCH_TEXELS, interpolated) and texel noise. Seeded by the look, so a track always has the same grain."""
    from scipy.ndimage import zoom

    rng = np.random.default_rng(look.grain_seed)
    coarse = rng.standard_normal((h // BLOTCH_TEXELS + 2, w // BLOTCH_TEXELS + 2)).astype(np.float32)
    blotch = zoom(coarse, BLOTCH_TEXELS, order=1)[:h, :w]
    blotch /= max(float(blotch.std()), 1e-6)
    return blotch, rng.standard_normal((h, w), dtype=np.float32)


def fine_grain(look: TrackLook) -> np.ndarray:
    """(FINE_TILE, FINE_TILE) int8 unit noise × 1 / FINE_SCALE: the grain finer than a raster texel, tiled over the
    ground at FINE_CELL_M per value (the renderer adds it where a pixel sees less than a texel)."""
    rng = np.random.default_rng([look.grain_seed, 1])
    unit = rng.standard_normal((FINE_TILE, FINE_TILE))
    return np.clip(np.rint(unit / FINE_SCALE), -127, 127).astype(np.int8)


_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_RECENT: list = []  # (track ref, look) of the cached rasters, oldest first
MAX_CACHED = 8  # rasters take 5-30 MB each and tracks stay loaded (racerlab.track.load caches them)


def track_raster(track: Track, look: TrackLook | None = None) -> TrackRaster:
    """The raster of `track`, built once per track object and look (a forward and a reversed track look the same,
    so pass the forward one); the last MAX_CACHED are kept."""
    look = look or TrackLook()
    per_track = _CACHE.setdefault(track, {})
    if look not in per_track:
        per_track[look] = TrackRaster(track, look)
        _RECENT.append((weakref.ref(track), look))
        while len(_RECENT) > MAX_CACHED:
            ref, old_look = _RECENT.pop(0)
            old = ref()
            if old is not None and old in _CACHE:
                _CACHE[old].pop(old_look, None)
    return per_track[look]
