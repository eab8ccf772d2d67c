"""Compiled camera renderer: image rows as straight ground lines read from the track raster.

For every car, eye and image row: rotate the row's ground lines (`RowPlan`) into the world and
step along each, one bilinear raster read per column at the level matching the pixel's footprint;
add the row's haze and, above the horizon, the background panorama turned by the car's yaw. With
a car's lighting not `plain` (domain randomization) the raster's ground and centre-paint fractions
are read too, so that each material takes its own grey under the car's light colour, and a tone
curve, a brightness gradient and noise follow. Output is truncated to uint8 as AWS's filter does.

Argument groups (tuples, so the signature stays readable):
- plan: row_first, row_haze, row_sky, sub_x, sub_y0, sub_dy, sub_level, sub_step, sub_weight, sky_el, sky_az
- raster: grey, ground, center (flat uint8 pyramids), off, stride, wmax, hmax, inv_cell, x0, y0
- lit: plain, coef, tone, light, noise_amp, noise, noise_off
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

TWO_PI = 2.0 * math.pi


@njit(cache=True, fastmath=True, inline="always")
def _bilinear(data, base, stride, ax, ay):
    v00 = np.float32(data[base])
    v01 = np.float32(data[base + 1])
    v10 = np.float32(data[base + stride])
    v11 = np.float32(data[base + stride + 1])
    top = v00 + ax * (v01 - v00)
    bot = v10 + ax * (v11 - v10)
    return top + ay * (bot - top)


@njit(cache=True, fastmath=True, inline="always")
def _lit(g, gf, cf, base, stride, ax, ay, kn, kg, kc):
    return kn * _bilinear(g, base, stride, ax, ay) + kg * _bilinear(gf, base, stride, ax, ay) \
        + kc * _bilinear(cf, base, stride, ax, ay)


@njit(cache=True, fastmath=True)
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


@njit(cache=True, fastmath=True)
def _lit_samples(raster, o, stride, wm, hm, clamp, fx, fy, sx, sy, wt, k3, dst, n):
    """As `_grey_samples`, with the neutral, ground and centre terms of a coloured light (k3)."""
    grey, gfrac, cfrac = raster[0], raster[1], raster[2]
    kn = np.float32(k3[0])
    kg = np.float32(k3[1])
    kc = np.float32(k3[2])
    x = fx
    y = fy
    for k in range(n):
        cx = min(max(x, np.float32(0.0)), wm) if clamp else x
        cy = min(max(y, np.float32(0.0)), hm) if clamp else y
        ix = np.int32(cx)
        iy = np.int32(cy)
        dst[k] += wt * _lit(grey, gfrac, cfrac, o + iy * stride + ix, stride, cx - np.float32(ix),
                            cy - np.float32(iy), kn, kg, kc)
        x += sx
        y += sy


@njit(cache=True, fastmath=True)
def _line(raster, level, fx0, fy0, sx, sy, wt, k3, dst, n):
    """dst[k] += wt · raster value at texel coordinates (fx0 + k·sx, fy0 + k·sy) of `level`, k < n.

    k3 = (neutral gain, ground, centre corrections) of the car's light; k3[0] < 0: the plain grey.
    Lines that stay inside the level skip the clamping.
    """
    wm = raster[5][level]
    hm = raster[6][level]
    fx1 = fx0 + (n - 1) * sx
    fy1 = fy0 + (n - 1) * sy
    clamp = not (min(fx0, fx1) >= 0.0 and max(fx0, fx1) <= wm and min(fy0, fy1) >= 0.0 and max(fy0, fy1) <= hm)
    args = (raster[3][level], raster[4][level], np.float32(wm), np.float32(hm), clamp, np.float32(fx0),
            np.float32(fy0), np.float32(sx), np.float32(sy), np.float32(wt))
    if k3[0] < 0.0:
        _grey_samples(raster[0], *args, dst, n)
    else:
        _lit_samples(raster, *args, k3, dst, n)


@njit(cache=True, fastmath=True)
def _spread(tmp, step, acc):
    """acc[col] += tmp interpolated linearly, tmp[j] being the value at column j · step."""
    inv = np.float32(1.0 / step)
    for j in range(acc.shape[0] // step):
        a = tmp[j]
        d = (tmp[j + 1] - a) * inv
        for q in range(step):
            acc[j * step + q] += a + q * d


@njit(cache=True, fastmath=True)
def _ground_row(r, ex, ey, c, s, plan, raster, k3, acc, tmp):
    """Add image row r's ground lines to acc; a row whose plan reads every step-th column fills in between."""
    row_first, sub_x, sub_y0, sub_dy, sub_level, sub_step, sub_weight = plan[0], plan[3], plan[4], plan[5], \
        plan[6], plan[7], plan[8]
    j0 = row_first[r]
    j1 = row_first[r + 1]
    if j1 == j0:
        return
    inv_cell, x0, y0 = raster[7], raster[8], raster[9]
    w = acc.shape[0]
    step = sub_step[j0]
    n = w if step == 1 else w // step + 1
    dst = acc if step == 1 else tmp
    if step > 1:
        dst[:n] = 0.0
    for j in range(j0, j1):
        lv = sub_level[j]
        ic = inv_cell[lv]
        ly = sub_y0[j]
        fx0 = (ex + c * sub_x[j] - s * ly - x0) * ic - 0.5
        fy0 = (ey + s * sub_x[j] + c * ly - y0) * ic - 0.5
        sd = sub_dy[j] * ic * step
        _line(raster, lv, fx0, fy0, -s * sd, c * sd, sub_weight[j], k3, dst, n)
    if step > 1:
        _spread(tmp, step, acc)


@njit(cache=True, fastmath=True)
def _sky_row(pano, el_row, az_row, yaw_bins, share, gain, acc):
    """acc[col] += share · gain · panorama at the pixel's azimuth turned by the car's yaw."""
    nb = pano.shape[1] - 1
    for col in range(acc.shape[0]):
        a = az_row[col] + yaw_bins
        a -= math.floor(a / nb) * nb
        i = min(int(a), nb - 1)
        fr = a - i
        p0 = pano[el_row[col], i]
        acc[col] += share * gain * (p0 + fr * (pano[el_row[col], i + 1] - p0))


@njit(cache=True, fastmath=True)
def _finish_row(acc, r, height, car, eye, lit, noff, out):
    """Tone curve, gradient and noise (unless plain), truncation to uint8 into out[car, r, :, eye]."""
    plain, tone, light, amp, noise = lit[0], lit[2], lit[3], lit[4], lit[5]
    w = acc.shape[0]
    if plain[car]:
        for col in range(w):
            out[car, r, col, eye] = np.uint8(min(max(acc[col], 0.0), 255.0))
        return
    gv = light[car, 0] + light[car, 2] * (2.0 * r / height - 1.0)
    gu = light[car, 1] * 2.0 / w
    a = amp[car]
    base = noff + r * w
    for col in range(w):
        v = min(max(acc[col], 0.0), 254.999)
        lo = int(v)
        t = tone[car, lo] + (v - lo) * (tone[car, lo + 1] - tone[car, lo])
        t = t * (gv + gu * (col - 0.5 * w)) + a * noise[base + col]
        out[car, r, col, eye] = np.uint8(min(max(t, 0.0), 255.0))


@njit(cache=True, fastmath=True)
def render(cars, pose_x, pose_y, pose_yaw, eyes, plan, raster, pano, lit, out):
    """Render cars `cars` into out[car, H, W, eye] (uint8) from base poses (x, y, yaw per car).

    `eyes` (E, 2): the cameras' foot points in the car frame (x ahead, y left).
    """
    row_haze, row_sky, sky_el, sky_az = plan[1], plan[2], plan[9], plan[10]
    plain, coef, noise_off = lit[0], lit[1], lit[6]
    height = out.shape[1]
    acc = np.empty(out.shape[2], dtype=np.float32)
    tmp = np.empty(out.shape[2] + 1, dtype=np.float32)
    k3 = np.empty(3)
    nb = pano.shape[1] - 1
    for k in range(cars.shape[0]):
        i = cars[k]
        c = math.cos(pose_yaw[i])
        s = math.sin(pose_yaw[i])
        if plain[i]:
            k3[0] = -1.0
        else:
            k3[0] = coef[i, 0]
            k3[1] = coef[i, 1] / 255.0
            k3[2] = coef[i, 2] / 255.0
        yaw_bins = pose_yaw[i] * (nb / TWO_PI)
        for eye in range(eyes.shape[0]):
            ex = pose_x[i] + c * eyes[eye, 0] - s * eyes[eye, 1]
            ey = pose_y[i] + s * eyes[eye, 0] + c * eyes[eye, 1]
            for r in range(height):
                acc[:] = row_haze[r] * coef[i, 3]
                if row_sky[r] > 0.0:
                    _sky_row(pano, sky_el[r], sky_az[r], yaw_bins, row_sky[r], coef[i, 4], acc)
                _ground_row(r, ex, ey, c, s, plan, raster, k3, acc, tmp)
                _finish_row(acc, r, height, i, eye, lit, noise_off[i, eye], out)
