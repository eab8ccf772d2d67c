"""Compiled camera renderer: image rows as straight ground lines read from the track raster.

For every car, eye and image row: rotate the row's ground lines (`RowPlan`) into the world and
step along each, one bilinear raster read per column at the level matching the pixel's footprint;
add the row's haze and, above the horizon, the background panorama turned by the car's yaw. With
a car's lighting not `plain` (domain randomization) the raster's ground and centre-paint fractions
are read too, so that each material takes its own grey under the car's light colour, and a tone
curve, a brightness gradient and noise follow. Output is truncated to uint8 as AWS's filter does.

Argument groups (tuples, so the signature stays readable; the kernel unpacks them once, before its loops, and its
helpers are inlined, because every array read from a tuple or passed to a compiled call costs reference counting):
- plan: row_first, row_haze, row_sky, lines (S, 7): per ground line its distance ahead, lateral offset of
  column 0 and step per column, raster level, column step, weight and fine grain's strength (`RowPlan`'s sub_*
  arrays side by side), sky_el, sky_az, edge_dir (H + 1, W, 3) rays through the rows' edges
- raster: grey, ground, center (flat uint8 pyramids), levels (L, 5): per level its first texel, stride, last
  column, last row and texels per metre; x0, y0
- lit: plain, coef, tone, light, noise_amp, noise, noise_off
- solids: pose (B, P, 3), dims (P, 4), grey (B, P), camera (cam_z, focal, cos pitch, sin pitch) — the objects
  each car sees (`racerlab.sim.sensors.solids`), drawn over the ground and sky where a pixel's ray meets one
- world: walls (bool), their box (x min, y min, x max, y max), height; the fine grain tile, its values per
  level-0 texel, its strength over grey (257,); the rounding bias added before the cast to uint8 (0: truncation
  as AWS's camera filter, 0.5: rounding as the PIL conversion of its stereo pair); whether the look has haze

With walls (the AWS look) each image row's top and bottom edges are intersected with the walls column by column:
a pixel shows the ground, the wall and the sky above it by the share of its height that sees each. Rows whose
pixels all see the wall are not sampled on the ground; below the lowest wall base no intersection is done.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from racerlab.sim.sensors.solids import FACES, FAR, face_greys, haze_fade, object_bounds, trace_row

TWO_PI = 2.0 * math.pi
WALL_STEP = 8  # columns between the rays intersected with the walls
# a texel's byte as float32 by a table read: one load, where the conversion takes two instructions more (a sixth of
# the frame's time)
U8_FLOAT = np.arange(256, dtype=np.float32)


@njit(cache=True, fastmath=True, inline="always")
def _bilinear(data, base, stride, ax, ay):
    # unsigned indices: numba checks a signed one for a negative value (to wrap it) on every read
    b = np.uint64(base)
    st = np.uint64(stride)
    one = np.uint64(1)
    v00 = U8_FLOAT[data[b]]
    v01 = U8_FLOAT[data[b + one]]
    v10 = U8_FLOAT[data[b + st]]
    v11 = U8_FLOAT[data[b + st + one]]
    top = v00 + ax * (v01 - v00)
    bot = v10 + ax * (v11 - v10)
    return top + ay * (bot - top)


@njit(cache=True, fastmath=True, inline="always")
def _grey_samples(grey, o, stride, wm, hm, clamp, fx, fy, sx, sy, wt, dst, n):
    """dst[k] += wt · bilinear grey at texel coordinates (fx + k·sx, fy + k·sy) of one level, k < n."""
    x = fx
    y = fy
    if clamp:
        for k in range(n):
            cx = min(max(x, np.float32(0.0)), wm)
            cy = min(max(y, np.float32(0.0)), hm)
            ix = np.int32(cx)
            iy = np.int32(cy)
            dst[k] += wt * _bilinear(grey, o + iy * stride + ix, stride, cx - np.float32(ix), cy - np.float32(iy))
            x += sx
            y += sy
    else:
        for k in range(n):
            ix = np.int32(x)
            iy = np.int32(y)
            dst[k] += wt * _bilinear(grey, o + iy * stride + ix, stride, x - np.float32(ix), y - np.float32(iy))
            x += sx
            y += sy


@njit(cache=True, fastmath=True, inline="always")
def _lit_samples(grey, gfrac, cfrac, o, stride, wm, hm, clamp, fx, fy, sx, sy, wt, kn, kg, kc, dst, n):
    """As `_grey_samples`, with the neutral, ground and centre terms of a coloured light (kn, kg, kc)."""
    x = fx
    y = fy
    for k in range(n):
        cx = x
        cy = y
        if clamp:
            cx = min(max(x, np.float32(0.0)), wm)
            cy = min(max(y, np.float32(0.0)), hm)
        ix = np.int32(cx)
        iy = np.int32(cy)
        ax = cx - np.float32(ix)
        ay = cy - np.float32(iy)
        base = o + iy * stride + ix
        dst[k] += wt * (kn * _bilinear(grey, base, stride, ax, ay) + kg * _bilinear(gfrac, base, stride, ax, ay)
                        + kc * _bilinear(cfrac, base, stride, ax, ay))
        x += sx
        y += sy


@njit(cache=True, fastmath=True, inline="always")
def _fine_grain(acc, fx, fy, sx, sy, gain, fine, amp):
    """acc[col] += gain · amp[acc[col]] · the fine tile's value under the pixel, the tile coordinates of column 0
    being (fx, fy) and stepping by (sx, sy) per column (in 16.16 fixed point, the cheapest way to wrap them).
    `fine` is the square tile flattened, its side a power of two."""
    side = np.int64(round(math.sqrt(fine.shape[0])))
    mask = side - 1
    bits = np.int64(round(math.log2(side)))
    gx = np.int64((fx + 1048576.0) * 65536.0)
    gy = np.int64((fy + 1048576.0) * 65536.0)
    dgx = np.int64(sx * 65536.0)
    dgy = np.int64(sy * 65536.0)
    top = np.float32(255.0)
    for col in range(acc.shape[0]):
        v = acc[col]
        t = fine[np.uint64((((gy >> 16) & mask) << bits) | ((gx >> 16) & mask))]
        acc[col] = v + gain * amp[np.uint32(min(max(v, np.float32(0.0)), top))] * np.float32(t)
        gx += dgx
        gy += dgy


@njit(cache=True, fastmath=True, inline="always")
def _spread(tmp, step, acc):
    """acc[col] += tmp interpolated linearly, tmp[j] being the value at column j · step."""
    inv = np.float32(1.0 / step)
    for j in range(acc.shape[0] // step):
        a = tmp[j]
        d = (tmp[j + 1] - a) * inv
        for q in range(step):
            acc[j * step + q] += a + q * d


@njit(cache=True, fastmath=True, inline="always")
def _sky_row(pano, sky_el, sky_az, r, yaw_bins, share, acc):
    """acc[col] += share · the panorama at row r's pixels' azimuths turned by the car's yaw."""
    nb = pano.shape[1] - 1
    for col in range(acc.shape[0]):
        # yaw_bins is in [0, nb) and the pixel's azimuth within half a turn, so one wrap each way is enough
        a = sky_az[r, col] + yaw_bins
        a = a + nb if a < 0.0 else a
        a = a - nb if a >= nb else a
        i = min(int(a), nb - 1)
        fr = a - i
        p0 = pano[sky_el[r, col], i]
        acc[col] += share * (p0 + fr * (pano[sky_el[r, col], i + 1] - p0))


@njit(cache=True, fastmath=True, inline="always")
def _fill(acc, value):
    v = np.float32(value)
    for col in range(acc.shape[0]):
        acc[col] = v


@njit(cache=True, fastmath=True, inline="always")
def _finish_plain(acc, bias, out, i, r, eye):
    """Row r of car i's eye `eye`: acc + bias, truncated to uint8."""
    lo = np.float32(0.0)
    hi = np.float32(255.0)
    for col in range(acc.shape[0]):
        out[i, r, col, eye] = np.uint8(np.int32(min(max(acc[col] + bias, lo), hi)))


@njit(cache=True, fastmath=True, inline="always")
def _finish_lit(acc, r, i, eye, tone, light, noise_amp, noise, base, bias, out):
    """Tone curve, brightness gradient and noise of car i's light, then truncation (after adding `bias`) to uint8
    into row r of its eye `eye`."""
    w = acc.shape[0]
    gv = light[i, 0] + light[i, 2] * (2.0 * r / out.shape[1] - 1.0)
    gu = light[i, 1] * 2.0 / w
    amp = noise_amp[i]
    for col in range(w):
        v = min(max(acc[col], 0.0), 254.999)
        lo = int(v)
        t = tone[i, lo] + (v - lo) * (tone[i, lo + 1] - tone[i, lo])
        t = t * (gv + gu * (col - 0.5 * w)) + amp * noise[base + col] + bias
        out[i, r, col, eye] = np.uint8(min(max(t, 0.0), 255.0))


@njit(cache=True, fastmath=True, inline="always")
def _wall_z(rays, row, c, s, ex, ey, cam_z, box, out):
    """out[k]: the height at which the ray of image-row edge `row` through column min(k · WALL_STEP, W - 1) (car
    frame, `rays` (H + 1, W, 3)) meets the walls `box` (x min, y min, x max, y max) around the eye at (ex, ey,
    cam_z) looking along (c, s): below 0 where the ray meets the ground first, above the wall's height where it
    passes over. The columns between are interpolated (`_expand`): the heights change smoothly along a row, but at
    a corner of the walls."""
    w = rays.shape[1]
    for k in range(out.shape[0]):
        q = min(k * WALL_STEP, w - 1)
        fx = rays[row, q, 0]
        fy = rays[row, q, 1]
        dx = c * fx - s * fy
        dy = s * fx + c * fy
        tx = FAR
        ty = FAR
        if dx > 1e-9:
            tx = (box[2] - ex) / dx
        elif dx < -1e-9:
            tx = (box[0] - ex) / dx
        if dy > 1e-9:
            ty = (box[3] - ey) / dy
        elif dy < -1e-9:
            ty = (box[1] - ey) / dy
        out[k] = cam_z + max(min(tx, ty), 0.0) * rays[row, q, 2]


@njit(cache=True, fastmath=True, inline="always")
def _expand(samples, out):
    """out[col]: `samples` (one every WALL_STEP columns, and the last column) interpolated linearly."""
    w = out.shape[0]
    for col in range(w):
        k = col // WALL_STEP
        q0 = k * WALL_STEP
        q1 = min(q0 + WALL_STEP, w - 1)
        if q1 == q0:
            out[col] = samples[k]
        else:
            out[col] = samples[k] + (samples[k + 1] - samples[k]) * (col - q0) / (q1 - q0)


@njit(cache=True, fastmath=True, inline="always")
def _blend_walls(acc, z_top, z_bot, height, wall, sky):
    """acc[col] = its ground grey, the wall's and the sky's, each by the share of the pixel's height that sees it
    (the height at the walls taken linear between the pixel's top and bottom edges)."""
    for col in range(acc.shape[0]):
        zt = z_top[col]
        zb = z_bot[col]
        span = max(zt - zb, 1e-9)
        ground = min(max(-zb / span, 0.0), 1.0)
        above = min(max((zt - height) / span, 0.0), 1.0)
        acc[col] = acc[col] * ground + sky * above + wall * max(1.0 - ground - above, 0.0)


@njit(cache=True, fastmath=True, inline="always")
def _wall_row(edge_dir, r, c, s, ex, ey, cam_z, box, zs_top, zs_bot):
    """Image row r's wall heights: the last row's bottom edge (`zs_bot`) becomes its top edge (`zs_top`) and its
    bottom edge's are worked out. Returns (the lowest at the bottom edge, the highest at the top edge)."""
    hi = zs_bot[0]
    for k in range(zs_top.shape[0]):
        zs_top[k] = zs_bot[k]
        hi = max(hi, zs_bot[k])
    _wall_z(edge_dir, r + 1, c, s, ex, ey, cam_z, box, zs_bot)
    lo = zs_bot[0]
    for k in range(zs_bot.shape[0]):
        lo = min(lo, zs_bot[k])
    return lo, hi


@njit(cache=True, fastmath=True, inline="always")
def _blend_row(acc, sky_share, zs_top, zs_bot, z_top, z_bot, wall_h, wall, sky):
    """Row acc (its ground lines read) as ground, wall and sky by the share of each pixel's height that sees each."""
    if 0.0 < sky_share < 1.0:
        f = np.float32(1.0 / (1.0 - sky_share))  # the ground lines cover only the part below the horizon
        for col in range(acc.shape[0]):
            acc[col] *= f
    _expand(zs_top, z_top)
    _expand(zs_bot, z_bot)
    _blend_walls(acc, z_top, z_bot, wall_h, wall, sky)


@njit(cache=True, fastmath=True, inline="always")
def _lines(j0, j1, n, ex, ey, c, s, plain, kn, kg, kc, lines, levels, grey, gfrac, cfrac, x0, y0, dst):
    """dst[k] += the ground lines j0..j1 (rows of `lines`: x ahead, y of column 0, y step per column, raster level,
    column step, weight, fine grain) read at n points each, seen from the eye at (ex, ey) looking along (c, s)."""
    for j in range(j0, j1):
        # the ground line in texel coordinates of its level (`levels` rows: offset, stride, w - 1, h - 1, 1 / cell)
        lv = np.int64(lines[j, 3])
        ic = levels[lv, 4]
        fx0 = (ex + c * lines[j, 0] - s * lines[j, 1] - x0) * ic - 0.5
        fy0 = (ey + s * lines[j, 0] + c * lines[j, 1] - y0) * ic - 0.5
        sd = lines[j, 2] * ic * lines[j, 4]
        sx = -s * sd
        sy = c * sd
        wm = levels[lv, 2]
        hm = levels[lv, 3]
        fx1 = fx0 + (n - 1) * sx
        fy1 = fy0 + (n - 1) * sy
        clamp = not (min(fx0, fx1) >= 0.0 and max(fx0, fx1) <= wm and min(fy0, fy1) >= 0.0 and max(fy0, fy1) <= hm)
        o = np.int64(levels[lv, 0])
        stride = np.int64(levels[lv, 1])
        if not plain:
            _lit_samples(grey, gfrac, cfrac, o, stride, np.float32(wm), np.float32(hm), clamp, np.float32(fx0),
                         np.float32(fy0), np.float32(sx), np.float32(sy), np.float32(lines[j, 5]), kn, kg, kc, dst, n)
        else:
            _grey_samples(grey, o, stride, np.float32(wm), np.float32(hm), clamp, np.float32(fx0), np.float32(fy0),
                          np.float32(sx), np.float32(sy), np.float32(lines[j, 5]), dst, n)


@njit(cache=True, fastmath=True, inline="always")
def _ground(j0, j1, ex, ey, c, s, plain, kn, kg, kc, lines, levels, grey, gfrac, cfrac, x0, y0, fine, fine_ratio,
            fine_amp, acc, tmp):
    """acc[col] += the ground lines j0..j1 of one image row (their share of each pixel), seen from the eye at
    (ex, ey) looking along (c, s): every step-th column read from the raster, the others interpolated."""
    if j1 <= j0:
        return
    width = acc.shape[0]
    step = np.int64(lines[j0, 4])
    if step == 1:
        _lines(j0, j1, width, ex, ey, c, s, plain, kn, kg, kc, lines, levels, grey, gfrac, cfrac, x0, y0, acc)
    else:
        n = width // step + 1
        for k in range(n):
            tmp[k] = 0.0
        _lines(j0, j1, n, ex, ey, c, s, plain, kn, kg, kc, lines, levels, grey, gfrac, cfrac, x0, y0, tmp)
        _spread(tmp, step, acc)
    if lines[j0, 6] > 0.0:
        # the fine grain, on the rows that read the finest level (one ground line each), added per column
        ic = levels[0, 4] * fine_ratio
        gx = (ex + c * lines[j0, 0] - s * lines[j0, 1] - x0) * ic
        gy = (ey + s * lines[j0, 0] + c * lines[j0, 1] - y0) * ic
        _fine_grain(acc, gx, gy, -s * lines[j0, 2] * ic, c * lines[j0, 2] * ic, np.float32(lines[j0, 6]), fine,
                    fine_amp)


@njit(cache=True, fastmath=True)
def render(cars, pose_x, pose_y, pose_yaw, eyes, plan, raster, pano, lit, solids, world, out):
    """Render cars `cars` into out[car, H, W, eye] (uint8) from base poses (x, y, yaw per car).

    `eyes` (E, 2): the cameras' foot points in the car frame (x ahead, y left).
    """
    # every array leaves its tuple here, once: a tuple read in the row loop costs two atomic reference counts per
    # array and row, which took an eighth of a frame's time
    row_first, row_haze, row_sky, lines, sky_el, sky_az, edge_dir = plan
    grey, gfrac, cfrac, levels, x0, y0 = raster
    plain, coef, tone, light, noise_amp, noise, noise_off = lit
    spose, sdims, sgrey, cam = solids
    walls, box, wall_h, fine, fine_ratio, fine_amp, bias, hazy = world
    bias = np.float32(bias)
    height, width = out.shape[1], out.shape[2]
    acc = np.empty(width, dtype=np.float32)
    tmp = np.empty(width + 1, dtype=np.float32)
    z_top = np.empty(width)
    z_bot = np.empty(width)
    nz = (width - 1 + WALL_STEP - 1) // WALL_STEP + 1
    zs_top = np.empty(nz)
    zs_bot = np.empty(nz)
    m = sgrey.shape[1]
    bounds = np.empty((m, 4), dtype=np.int64)
    seen = np.empty(m, dtype=np.int64)
    shades = np.empty((m, FACES))
    local = np.empty((m, 4))  # camera x, y in the object's frame, cos / sin (car yaw - object yaw)
    zbuf = np.empty(width)
    val = np.empty(width)
    nb = pano.shape[1] - 1
    cam_z = cam[0]
    for k in range(cars.shape[0]):
        i = cars[k]
        c = math.cos(pose_yaw[i])
        s = math.sin(pose_yaw[i])
        kn = np.float32(coef[i, 0])
        kg = np.float32(coef[i, 1] / 255.0)
        kc = np.float32(coef[i, 2] / 255.0)
        yaw_bins = pose_yaw[i] * (nb / TWO_PI)
        yaw_bins -= math.floor(yaw_bins / nb) * nb
        for eye in range(eyes.shape[0]):
            ex = pose_x[i] + c * eyes[eye, 0] - s * eyes[eye, 1]
            ey = pose_y[i] + s * eyes[eye, 0] + c * eyes[eye, 1]
            nseen = _see_objects(i, ex, ey, c, s, pose_yaw[i], spose, sdims, sgrey, cam, coef[i, 0],
                                 coef[i, 3] if hazy else -1.0, width, height, bounds, seen, shades, local)
            in_walls = walls
            if walls:
                _wall_z(edge_dir, 0, c, s, ex, ey, cam_z, box, zs_bot)
            for r in range(height):
                ground = True
                blend = False
                flat = False
                hi = 0.0
                if in_walls:
                    lo, hi = _wall_row(edge_dir, r, c, s, ex, ey, cam_z, box, zs_top, zs_bot)
                    in_walls = hi > 0.0  # once every pixel's top edge sees the ground, so do all rows below
                    ground = lo < 0.0
                    flat = not ground and (hi <= wall_h or lo >= wall_h)  # all wall, or all sky above it
                    blend = in_walls and not flat
                if flat:
                    _fill(acc, coef[i, 5] if hi <= wall_h else coef[i, 6])
                else:
                    _fill(acc, row_haze[r] * coef[i, 3])
                    if row_sky[r] > 0.0 and not walls:
                        _sky_row(pano, sky_el, sky_az, r, yaw_bins, row_sky[r] * coef[i, 4], acc)
                    _ground(row_first[r], row_first[r + 1] if ground else row_first[r], ex, ey, c, s, plain[i], kn,
                            kg, kc, lines, levels, grey, gfrac, cfrac, x0, y0, fine, fine_ratio, fine_amp, acc, tmp)
                if blend:
                    _blend_row(acc, row_sky[r], zs_top, zs_bot, z_top, z_bot, wall_h, coef[i, 5], coef[i, 6])
                if nseen:
                    _objects_row(r, nseen, bounds, seen, shades, local, sdims, cam, width, height, zbuf, val, acc)
                if plain[i]:
                    _finish_plain(acc, bias, out, i, r, eye)
                else:
                    _finish_lit(acc, r, i, eye, tone, light, noise_amp, noise, noise_off[i, eye] + r * width, bias,
                                out)


@njit(cache=True, fastmath=True)
def _see_objects(i, ex, ey, c, s, yaw, spose, sdims, sgrey, cam, gain, haze, width, height, bounds, seen, shades,
                 local):
    """Car i's objects in view of the eye at (ex, ey): their indices into `seen`, pixel bounds, face greys (lit
    by the car's neutral light `gain`, faded into `haze` with distance as the ground is, unless `haze` < 0: a look
    without haze) and the camera in each one's frame."""
    cam_z, f, cp, sp = cam
    n = 0
    for q in range(sgrey.shape[1]):
        ox = spose[i, q, 0]
        oy = spose[i, q, 1]
        oyaw = spose[i, q, 2]
        if not object_bounds(ex, ey, c, s, ox, oy, oyaw, sdims[q, 0], sdims[q, 1], sdims[q, 2], sdims[q, 3], cam_z,
                             cp, sp, f, width, height, bounds[n]):
            continue
        face_greys(oyaw, sgrey[i, q] * gain, shades[n])
        fade = haze_fade(c * (ox - ex) + s * (oy - ey)) if haze >= 0.0 else 0.0
        for k in range(FACES):
            shades[n, k] = shades[n, k] * (1.0 - fade) + haze * fade
        co = math.cos(oyaw)
        so = math.sin(oyaw)
        local[n, 0] = co * (ex - ox) + so * (ey - oy)
        local[n, 1] = -so * (ex - ox) + co * (ey - oy)
        local[n, 2] = math.cos(yaw - oyaw)
        local[n, 3] = math.sin(yaw - oyaw)
        seen[n] = q
        n += 1
    return n


@njit(cache=True, fastmath=True)
def _objects_row(r, nseen, bounds, seen, shades, local, sdims, cam, width, height, zbuf, val, acc):
    """Overwrite row r's pixels whose rays meet one of the objects in view with the nearest one's face grey."""
    cam_z, f, cp, sp = cam
    vv = (r + 0.5 - 0.5 * height) / f
    dxr = cp - vv * sp
    dz = -sp - vv * cp
    lo = width
    hi = -1
    for n in range(nseen):
        if bounds[n, 0] <= r <= bounds[n, 1]:
            if hi < 0:
                zbuf[:] = FAR
            q = seen[n]
            trace_row(dxr, dz, bounds[n, 2], bounds[n, 3], (0.5 - 0.5 * width) / f, 1.0 / f, local[n, 0],
                      local[n, 1], cam_z, local[n, 2], local[n, 3], sdims[q, 0], sdims[q, 1], sdims[q, 2], sdims[q, 3],
                      shades[n], zbuf, val)
            lo = min(lo, bounds[n, 2])
            hi = max(hi, bounds[n, 3])
    for k in range(lo, hi + 1):
        if zbuf[k] < FAR:
            acc[k] = val[k]
