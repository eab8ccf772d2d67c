"""Solid objects the sensors see: the boxes of an object avoidance race, the bot cars of a head-to-bot race and the
other car of a head-to-model race.

Each object is made of upright blocks (parts): `Solids` packs every car's objects (the car axis first, read
from the simulator's `ObjectSet` at each frame, because objects move at resets and bot cars drive), one entry
per part: its pose, half length (along the object's yaw), half width, bottom and top height, and per car its
grey under white light.

- A box is one block, AWS's `box_obstacle` model, 0.40 × 0.30 × 0.25 m (next_capabilities §A.1), in the look's
  `box` colour (cardboard, light against the dark road).
- A bot car (or the other racer) is car-shaped (`BOT_CAR_PARTS`): a body block the length of the car's crash
  footprint (0.324 m), 0.14 m wide, from 0.035 m to `BOT_CAR_HEIGHT_M` above the ground, in the look's darker
  `bot_car` colour, on four wheel blocks (0.065 m long and high, 0.031 m wide, the outer faces at the
  footprint's 0.196 m width) in the `tyre` colour: the road shows under the body between the wheels. (AWS
  renders the DeepRacer car's mesh; racerlab draws these five blocks. The crash footprint is the rectangle
  either way.)
- Under domain randomization every car draws, at each episode start, a random colour (RGB uniform in
  [0, 255]) for each obstacle and for each part of a bot car, as AWS gives obstacles a whole-model random
  colour and bot cars per-visual ones (next_capabilities §A.1, §A.2); the colour is lit by the car's light.

The camera renderer (`_render.render`) traces each pixel's ray against the objects whose projected corners
cover it (`object_bounds`, `trace_row`): the nearest face wins. The ground is flat and the objects stand on
it, so a ray that meets an object meets it before the ground: an object always hides the road behind it and
never hides the road in front of it. Faces are shaded by a fixed light (`face_greys`): the top brightest,
each side by how much it faces the light (half-Lambert, so that no two sides look alike), and far objects
fade into the haze as the ground does.

Numba caches `_render.render` with these kernels compiled in, keyed on `_render.py` alone: after editing this
file, delete `sensors/__pycache__/_render.*.nbi` (or touch `_render.py`), or the renderer keeps the old code.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from racerlab.sim.sensors.geometry import HAZE_FAR_M, HAZE_NEAR_M
from racerlab.sim.sensors.look import LUMA

BOX_MODEL_M = (0.40, 0.30, 0.25)  # box_obstacle / amazon_box_obstacle model.sdf (x along the lane, y, z)
BOT_CAR_HEIGHT_M = 0.20  # the top of a bot car's body: about the DeepRacer's height with its lidar
# a bot car's blocks in its frame (x ahead, y left): x, y of the centre, half length, half width, bottom, top (m),
# and the look's colour; the wheels' outer faces are at the crash footprint's half width (0.098 m)
BOT_CAR_PARTS = (
    (0.0, 0.0, 0.16176, 0.07, 0.035, BOT_CAR_HEIGHT_M, "bot_car"),
    (0.105, 0.0825, 0.0325, 0.0155, 0.0, 0.065, "tyre"),
    (0.105, -0.0825, 0.0325, 0.0155, 0.0, 0.065, "tyre"),
    (-0.105, 0.0825, 0.0325, 0.0155, 0.0, 0.065, "tyre"),
    (-0.105, -0.0825, 0.0325, 0.0155, 0.0, 0.065, "tyre"),
)
NEAR_M = 0.01  # the camera sees objects from this far ahead of its plane
LIGHT_DIR = (math.cos(math.radians(35.0)), math.sin(math.radians(35.0)))  # world frame, horizontal part
AMBIENT, DIFFUSE, TOP = 0.6, 0.4, 1.0  # a face's grey: albedo · (AMBIENT + DIFFUSE · (1 + n·l) / 2)
FACES = 5  # +x, -x, +y, -y (in the object's frame), top
FAR = 1e30  # "no hit" ray parameter: finite, because the kernels are compiled with fastmath (no infinities)


@njit(cache=True, fastmath=True)
def face_greys(yaw, grey, out):
    """out[5]: the grey of each face (+x, -x, +y, -y, top) of an object turned by `yaw` with albedo `grey`."""
    co = math.cos(yaw)
    so = math.sin(yaw)
    lx, ly = LIGHT_DIR
    nx = (co, -co, -so, so)
    ny = (so, -so, co, -co)
    for f in range(4):
        out[f] = grey * (AMBIENT + DIFFUSE * 0.5 * (1.0 + nx[f] * lx + ny[f] * ly))
    out[4] = grey * TOP


@njit(cache=True, fastmath=True)
def object_bounds(ex, ey, c, s, ox, oy, oyaw, hl, hw, z0, z1, cam_z, cp, sp, f, width, height, out):
    """Pixel rows and columns (out = r0, r1, c0, c1, inclusive) whose centres may see an upright box (centre ox, oy,
    turned by oyaw, half sizes hl, hw, from height z0 to z1) from a camera at (ex, ey, cam_z) looking along (c, s),
    pitched down (cp = cos, sp = sin). Returns False when the box is behind the camera or outside the image.

    The bounds are those of the box's part in front of the plane NEAR_M ahead of the camera: its corners there,
    and where its edges cross that plane."""
    co = math.cos(oyaw)
    so = math.sin(oyaw)
    fwd = np.empty(8)  # along the optical axis
    right = np.empty(8)
    down = np.empty(8)
    for q in range(8):
        a = hl if q & 1 else -hl
        b = hw if q & 2 else -hw
        fz = (z1 if q & 4 else z0) - cam_z
        wx = ox + co * a - so * b - ex
        wy = oy + so * a + co * b - ey
        fx = c * wx + s * wy
        fwd[q] = fx * cp - fz * sp
        right[q] = s * wx - c * wy
        down[q] = -fx * sp - fz * cp
    lim = np.array([1e30, -1e30, 1e30, -1e30])  # u min, u max, v min, v max
    for q in range(8):
        if fwd[q] > NEAR_M:
            _extend(lim, right[q] / fwd[q], down[q] / fwd[q])
        for bit in (1, 2, 4):  # the edges from this corner that cross the near plane
            p = q | bit
            if p != q and (fwd[q] > NEAR_M) != (fwd[p] > NEAR_M):
                w = (NEAR_M - fwd[q]) / (fwd[p] - fwd[q])
                _extend(lim, (right[q] + w * (right[p] - right[q])) / NEAR_M,
                        (down[q] + w * (down[p] - down[q])) / NEAR_M)
    if lim[0] > lim[1]:
        return False
    # pixel k's centre is at k + 0.5: the centres inside [min, max]
    out[0] = max(int(math.ceil(max(lim[2] * f + 0.5 * height, -1.0) - 0.5)), 0)
    out[1] = min(int(math.floor(min(lim[3] * f + 0.5 * height, height + 1.0) - 0.5)), height - 1)
    out[2] = max(int(math.ceil(max(lim[0] * f + 0.5 * width, -1.0) - 0.5)), 0)
    out[3] = min(int(math.floor(min(lim[1] * f + 0.5 * width, width + 1.0) - 0.5)), width - 1)
    return out[0] <= out[1] and out[2] <= out[3]


@njit(cache=True, fastmath=True, inline="always")
def _extend(lim, u, v):
    lim[0] = min(lim[0], u)
    lim[1] = max(lim[1], u)
    lim[2] = min(lim[2], v)
    lim[3] = max(lim[3], v)


@njit(cache=True, fastmath=True, inline="always")
def _nonzero(d):
    """d moved off zero (the kernels are compiled with fastmath, which assumes no infinities from 1 / 0)."""
    return d if abs(d) > 1e-12 else 1e-12


@njit(cache=True, fastmath=True)
def trace_row(dxr, dz, c0, c1, u0, du, lx, ly, oz, ca, sa, hl, hw, z0, z1, shades, zbuf, val):
    """For columns c0..c1 of one image row: where the pixel's ray hits the box nearer than zbuf, set zbuf to the
    hit's ray parameter and val to the face's grey shades[face].

    The ray of column k is (dxr, -(u0 + k·du), dz) in the car frame (x ahead, y left, z up), from the camera at
    (lx, ly, oz) in the box's frame, which is the car frame turned by (ca, sa) = cos, sin(car yaw − box yaw).
    The box spans [-hl, hl] × [-hw, hw] × [z0, z1]. Slabs: the ray is inside the box between the largest entry
    and the smallest exit of the three axes' slabs; the axis of the largest entry is the face it meets.
    """
    iz = 1.0 / _nonzero(dz)  # the z slab is the same for the whole row
    za = (z0 - oz) * iz
    zb = (z1 - oz) * iz
    tz0 = min(za, zb)
    tz1 = max(za, zb)
    dx0 = ca * dxr + sa * u0  # the ray's box-frame x and y are linear in the column
    dy0 = sa * dxr - ca * u0
    ddx = sa * du
    ddy = -ca * du
    for k in range(c0, c1 + 1):
        dx = _nonzero(dx0 + k * ddx)
        dy = _nonzero(dy0 + k * ddy)
        ix = 1.0 / dx
        iy = 1.0 / dy
        xa = (-hl - lx) * ix
        xb = (hl - lx) * ix
        ya = (-hw - ly) * iy
        yb = (hw - ly) * iy
        tx0 = min(xa, xb)
        ty0 = min(ya, yb)
        t_in = max(tx0, max(ty0, tz0))
        t_out = min(max(xa, xb), min(max(ya, yb), tz1))
        if 0.0 < t_in <= t_out and t_in < zbuf[k]:
            zbuf[k] = t_in
            if t_in == tz0:
                val[k] = shades[4]
            elif t_in == tx0:
                val[k] = shades[1] if dx > 0.0 else shades[0]
            else:
                val[k] = shades[3] if dy > 0.0 else shades[2]


@njit(cache=True, fastmath=True)
def haze_fade(ahead_m):
    """The share of haze over an object this far ahead of the camera, as over the ground (`RowPlan`)."""
    return min(max((ahead_m - HAZE_NEAR_M) / (HAZE_FAR_M - HAZE_NEAR_M), 0.0), 1.0) ** 0.7


class Solids:
    """Every car's objects as the camera sees them, part by part: `pose` (B, P, 3) x, y, yaw of each part, refreshed
    by `update`; per part `dims` (P, 4) half length, half width, bottom, top; `grey` (B, P) under white light."""

    def __init__(self, sim, look):
        objects = getattr(sim, "objects", None)
        self.objects = objects if objects is not None and objects.num_objects else None
        m = self.objects.num_objects if self.objects is not None else 0
        o = self.objects
        cars = bool(m and (getattr(o, "bots", False) or getattr(o, "racers", False)))  # bot cars, or the other racer
        if cars:
            parts = BOT_CAR_PARTS
        else:
            length, width = (float(v) for v in o.box_size_m) if m else BOX_MODEL_M[:2]
            parts = ((0.0, 0.0, 0.5 * length, 0.5 * width, 0.0, BOX_MODEL_M[2], "box"),)
        k = len(parts)
        self.parts = k
        self.offset = np.array([p[:2] for p in parts], dtype=np.float64)  # (k, 2) in the object's frame
        self.shifted = bool(self.offset.any())
        self.dims = np.tile(np.array([p[2:6] for p in parts], dtype=np.float64), (m, 1))
        self.pose = np.zeros((sim.num_cars, m * k, 3))
        self.grey = np.tile([look.material_grey(p[6]) for p in parts], (sim.num_cars, m)).astype(np.float64)

    @property
    def count(self) -> int:
        return int(self.grey.shape[1])

    def update(self) -> None:
        """Read the objects' current poses (they move at every reset, and bot cars at every step)."""
        if self.objects is None:
            return
        xy, yaw = self.objects.xy, self.objects.yaw
        if not self.shifted:  # one block per object at its centre (boxes)
            self.pose[:, :, :2] = xy
            self.pose[:, :, 2] = yaw
            return
        c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]  # (B, M, 1)
        dx, dy = self.offset[:, 0], self.offset[:, 1]
        n = yaw.shape[0]
        self.pose[:, :, 0] = (xy[..., 0:1] + c * dx - s * dy).reshape(n, -1)
        self.pose[:, :, 1] = (xy[..., 1:2] + s * dx + c * dy).reshape(n, -1)
        self.pose[:, :, 2] = np.repeat(yaw, self.parts, axis=1)

    def recolour(self, rows: np.ndarray, light_rgb: np.ndarray, rng: np.random.Generator) -> None:
        """Domain randomization: a random colour for every part of cars `rows`' objects (RGB uniform in [0, 255]),
        stored as the grey that, times the car's neutral gain, is the colour's grey under its light `light_rgb`
        (n, 3)."""
        if self.count == 0 or rows.size == 0:
            return
        colour = rng.uniform(0.0, 255.0, size=(rows.size, self.count, 3))
        lit = (colour * light_rgb[:, None, :]) @ LUMA
        self.grey[rows] = lit / (light_rgb @ LUMA)[:, None]
