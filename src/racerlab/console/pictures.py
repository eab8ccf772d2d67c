"""Small SVG pictures drawn by hand: a track for the track picker and the live view."""

from __future__ import annotations

import numpy as np

WIDTH_PX = 320


def _path(points: np.ndarray, fx, fy) -> str:
    xs, ys = fx(points[:, 0]), fy(points[:, 1])
    return "M" + " L".join(f"{x:.1f},{y:.1f}" for x, y in zip(xs, ys, strict=True)) + (" Z" if len(xs) > 2 else "")


def track_frame(track, width_px: int = WIDTH_PX, margin_m: float = 0.3) -> dict:
    """The metres → pixels mapping of a track picture (y up in metres, down in pixels)."""
    pts = np.vstack([track.inner, track.outer])
    lo = pts.min(axis=0) - margin_m
    hi = pts.max(axis=0) + margin_m
    scale = width_px / (hi[0] - lo[0])
    return {"x0": float(lo[0]), "y1": float(hi[1]), "scale": float(scale), "width": width_px,
            "height": int(np.ceil((hi[1] - lo[1]) * scale))}


def track_svg(track, width_px: int = WIDTH_PX) -> str:
    """Road (grey between the borders), centre line (dashed), start line (white) as an SVG document."""
    f = track_frame(track, width_px)

    def fx(x):
        return (x - f["x0"]) * f["scale"]

    def fy(y):
        return (f["y1"] - y) * f["scale"]

    outer, inner, center = _path(track.outer, fx, fy), _path(track.inner, fx, fy), _path(track.center, fx, fy)
    a, b = track.inner[0], track.outer[0]
    start = f'<line x1="{fx(a[0]):.1f}" y1="{fy(a[1]):.1f}" x2="{fx(b[0]):.1f}" y2="{fy(b[1]):.1f}" ' \
            'stroke="#fff" stroke-width="3"/>'
    meta = (f'data-x0="{f["x0"]:.4f}" data-y1="{f["y1"]:.4f}" data-scale="{f["scale"]:.4f}"')
    return (f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {f["width"]} {f["height"]}" '
            f'width="{f["width"]}" height="{f["height"]}" {meta}>'
            f'<rect width="100%" height="100%" fill="#2d5a27"/>'
            f'<path d="{outer} {inner}" fill="#555" fill-rule="evenodd" stroke="#ddd" stroke-width="1"/>'
            f'<path d="{center}" fill="none" stroke="#f3d250" stroke-width="1" stroke-dasharray="4 4"/>'
            f'{start}</svg>')
