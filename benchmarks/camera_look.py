"""How close racerlab's camera looks to the AWS simulator's: grey-level histograms and asphalt grain against real
frames, and a side-by-side picture.

The real frames are the simulator's own observations in `../shared/reference/gazebo_frames` (120×160 greyscale,
front camera and stereo, from the sample transitions the simapp ships). racerlab renders `--frames` frames at
random on-track poses of `--track` (reinvent_base by default: position anywhere along the lap and up to 0.25 m
either side of the centre line, heading within ±30° of the track's) and prints one JSON line per camera
(`camera`, `stereo`):

- `wasserstein`: per region, the Wasserstein distance (earth mover's, in grey levels) between the pooled
  grey-level histograms of the real frames and of racerlab's: the whole frame, the top 20 rows (what lies
  beyond the track), the bottom third (the road just ahead). 0 = the same distribution of greys;
- `grain`: the asphalt grain, the median |difference between horizontal neighbours| in the bottom third, over
  pairs of pixels both below the white level (200), for the real frames and for racerlab's (`grain_mean`: their
  mean, which moves in finer steps than the median of whole grey levels);
- `region_means`: mean grey of each region, real and racerlab, to see which way a distance goes;
- `chance`: what a perfect look would still score: the distances between racerlab's pool and as many frames
  drawn from it as the real set holds (its views: a stereo pair counts once), median and 90th percentile over
  200 draws. The real sets are four views each, so a pooled distance below the 90th percentile is within what
  the mix of views alone gives;
- stereo only, `disparity_px`: how far the right eye's view of the ground is shifted against the left eye's, in
  whole pixels, on 8-row bands starting at rows 45, 60, 80, 100 and 112 (median over the frames): it grows as
  B·cos 15°/h per row below the horizon, so it checks the eyes' baseline B against the camera's height h.

`matched` gives the same measures between each distinct real frame and the racerlab frame most like it, picked
from `--candidates` random poses (heading within ±45°, so that views across the field are among them) by the
mean absolute difference of 4×4-pixel block means (the real poses are not recorded): the look at a similar pose,
whatever the mix of views (the stereo pairs: both eyes of the pose whose left eye matches). `--png FILE` writes
those pairs side by side. `--look NAME` renders a named look of
`racerlab.sim.sensors.look.LOOKS` instead of the default.

Usage: python benchmarks/camera_look.py [--track reinvent_base] [--frames 256] [--png camera_look.png]
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path

import numpy as np

from racerlab.sim import Simulator
from racerlab.sim import _kernels as K
from racerlab.sim.sensors import Camera
from racerlab.track import load_file

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
REAL = SHARED / "reference" / "gazebo_frames"
WHITE = 200  # grain is measured between pixels darker than this (the white lines are left out)
TOP_ROWS = 20
SIDE_M = 0.25  # poses: up to this far either side of the centre line
YAW_DEG = 30.0  # and headings within this of the track's
MATCH_YAW_DEG = 45.0  # candidates for the real frames' look-alikes


def real_frames(stereo: bool) -> dict[str, np.ndarray]:
    """name -> (120, 160) uint8 frame; stereo frames give two entries, `<name>_left` and `<name>_right`."""
    out = {}
    for f in sorted(REAL.glob("*.npy")):
        a = np.load(f)
        if a.ndim == 3 and stereo:
            out[f"{f.stem}_left"], out[f"{f.stem}_right"] = a[..., 0], a[..., 1]
        elif a.ndim == 2 and not stereo:
            out[f.stem] = a
    if not out:
        raise SystemExit(f"no real frames in {REAL}: the reference data sits beside the checkout (../shared)")
    return out


def regions(frames: np.ndarray) -> dict[str, np.ndarray]:
    """(N, 120, 160) frames -> their pixels per region."""
    h = frames.shape[1]
    return {"frame": frames, "top_20_rows": frames[:, :TOP_ROWS], "bottom_third": frames[:, h - h // 3:]}


def wasserstein(a: np.ndarray, b: np.ndarray) -> float:
    """Earth mover's distance between the grey-level histograms of two uint8 arrays, in grey levels."""
    ca = np.cumsum(np.bincount(a.ravel(), minlength=256)) / a.size
    cb = np.cumsum(np.bincount(b.ravel(), minlength=256)) / b.size
    return float(np.abs(ca - cb).sum())


def grain(frames: np.ndarray, stat=np.median) -> float:
    """Median (or `stat`) |horizontal neighbour difference| in the bottom third, over pairs both darker than WHITE."""
    bottom = frames[:, frames.shape[1] - frames.shape[1] // 3:].astype(np.int16)
    left, right = bottom[:, :, :-1], bottom[:, :, 1:]
    keep = (left < WHITE) & (right < WHITE)
    return round(float(stat(np.abs(right - left)[keep])), 2) if keep.any() else float("nan")


BANDS = (45, 60, 80, 100, 112)


def eye_shift(left: np.ndarray, right: np.ndarray, r0: int) -> int:
    """The whole-pixel shift of the right eye's rows r0..r0+7 that lines them up best with the left eye's."""
    a, b = left[r0:r0 + 8].astype(np.float32), right[r0:r0 + 8].astype(np.float32)
    return int(np.argmin([np.abs(a[:, s:] - b[:, :a.shape[1] - s]).mean() for s in range(60)]))


def disparity(pairs: np.ndarray) -> list[float]:
    """(N, 120, 160, 2) stereo frames -> the median eye shift per band (`BANDS`) over the frames."""
    return [float(np.median([eye_shift(p[..., 0], p[..., 1], r0) for p in pairs])) for r0 in BANDS]


def chance(ours: np.ndarray, views: int, eyes: int, rng, draws: int = 200) -> dict:
    """Distances per region between racerlab's pooled frames (views × eyes of them, eyes stacked after each other)
    and `views` of its own views drawn at random: the spread a real set of that size shows with a perfect look."""
    n = len(ours) // eyes
    pool = regions(ours)
    d = []
    for _ in range(draws):
        k = rng.choice(n, views, replace=False)
        drawn = regions(np.concatenate([ours[k + e * n] for e in range(eyes)]))
        d.append([wasserstein(drawn[r], pool[r]) for r in pool])
    d = np.array(d)
    return {r: [round(float(np.median(d[:, j])), 1), round(float(np.percentile(d[:, j], 90)), 1)]
            for j, r in enumerate(pool)}


def random_poses(track, n: int, rng, yaw_deg: float = YAW_DEG) -> np.ndarray:
    """(n, 3) base poses x, y, yaw on the road: anywhere along the lap, near the centre line, roughly along it."""
    s = rng.uniform(0.0, track.length, n)
    side = rng.uniform(-SIDE_M, SIDE_M, n)
    xy = track.point_at(s)
    heading = track.heading_at(s)
    xy = xy + side[:, None] * np.column_stack([-np.sin(heading), np.cos(heading)])
    yaw = heading + np.radians(rng.uniform(-yaw_deg, yaw_deg, n))
    return np.column_stack([xy, yaw])


def render(track, poses: np.ndarray, stereo: bool, look=None) -> np.ndarray:
    """(N, 120, 160, eyes) frames of cars at `poses`."""
    sim = Simulator(track, len(poses), seed=0)
    cam = Camera(sim, stereo=stereo) if look is None else Camera(sim, stereo=stereo, look=look)
    sim.car[:, K.CX], sim.car[:, K.CY], sim.car[:, K.CYAW] = poses.T
    return cam.render().copy()


def measure(real: np.ndarray, ours: np.ndarray) -> dict:
    r, o = regions(real), regions(ours)
    return {"wasserstein": {k: round(wasserstein(r[k], o[k]), 1) for k in r},
            "region_means": {k: [round(float(r[k].mean()), 1), round(float(o[k].mean()), 1)] for k in r},
            "grain": {"real": grain(real), "racerlab": grain(ours)},
            "grain_mean": {"real": grain(real, np.mean), "racerlab": grain(ours, np.mean)}}


def distinct(frames: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The frames without near-duplicates (the sample transitions repeat some views)."""
    out: dict[str, np.ndarray] = {}
    for k, f in frames.items():
        if all(np.abs(f.astype(float) - g).mean() > 4.0 for g in out.values()):
            out[k] = f
    return out


def blocks(frames: np.ndarray) -> np.ndarray:
    n, h, w = frames.shape
    return frames.reshape(n, h // 4, 4, w // 4, 4).mean(axis=(2, 4))


def nearest(real: dict[str, np.ndarray], candidates: np.ndarray) -> dict[str, int]:
    """For each real frame, the index of the candidate frame (N, 120, 160) whose 4×4 block means differ least from
    it."""
    cb = blocks(candidates.astype(np.float32))
    return {k: int(np.abs(cb - blocks(f[None].astype(np.float32))).mean(axis=(1, 2)).argmin()) for k, f in real.items()}


def picture(pairs: list[tuple[str, np.ndarray, np.ndarray]], path: Path, scale: int = 2) -> None:
    """Rows of (real | racerlab) frames, labelled, written as a PNG."""
    from PIL import Image, ImageDraw

    h, w = 120 * scale, 160 * scale
    pad, head = 6, 18
    cols = 2
    per_row = 2  # pairs per picture row
    rows = math.ceil(len(pairs) / per_row)
    img = Image.new("L", (per_row * (cols * w + pad) + pad * per_row, head + rows * (h + pad + 14)), 255)
    draw = ImageDraw.Draw(img)
    for j in range(per_row):
        x0 = j * (cols * w + 2 * pad)
        draw.text((x0 + 4, 3), "AWS simulator", fill=0)
        draw.text((x0 + w + pad + 4, 3), "racerlab", fill=0)
    for i, (name, real, ours) in enumerate(pairs):
        r, j = divmod(i, per_row)
        x0 = j * (cols * w + 2 * pad)
        y0 = head + r * (h + pad + 14)
        for c, f in enumerate((real, ours)):
            big = Image.fromarray(np.ascontiguousarray(f)).resize((w, h), Image.NEAREST)
            img.paste(big, (x0 + c * (w + pad), y0))
        draw.text((x0 + 4, y0 + h + 1), name, fill=90)
    img.save(path, optimize=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default=str(SHARED / "tracks" / "reinvent_base.npy"))
    ap.add_argument("--frames", type=int, default=256)
    ap.add_argument("--candidates", type=int, default=4000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--look", default=None, help="a named look (racerlab.sim.sensors.look.LOOKS)")
    ap.add_argument("--png", type=Path, default=None)
    args = ap.parse_args()
    track = load_file(args.track)
    look = None
    if args.look:
        from racerlab.sim.sensors.look import LOOKS

        look = LOOKS[args.look]
    rng = np.random.default_rng(args.seed)
    pairs = []
    for stereo in (False, True):
        real = real_frames(stereo)
        rendered = render(track, random_poses(track, args.frames, rng), stereo, look)
        ours = np.concatenate([rendered[..., e] for e in range(rendered.shape[-1])])
        line = {"bench": "camera_look", "camera": "stereo" if stereo else "camera", "track": track.name,
                "look": args.look or "default", "real_frames": len(real), "racerlab_frames": len(ours)}
        line.update(measure(np.stack(list(real.values())), ours))
        views = len(real) // rendered.shape[-1]
        line["chance"] = chance(ours, views, rendered.shape[-1], rng)
        cand = render(track, random_poses(track, args.candidates, rng, MATCH_YAW_DEG), stereo, look)
        eyes = {k: f for k, f in distinct(real).items() if not k.endswith("_right")}
        match = nearest(eyes, cand[..., 0])
        line["matched"] = measure(np.stack(list(eyes.values())), np.stack([cand[i, ..., 0] for i in match.values()]))
        if stereo:
            pairs_real = np.stack([np.load(f) for f in sorted(REAL.glob("stereo*.npy"))])
            line["disparity_px"] = {"bands_from_row": list(BANDS), "real": disparity(pairs_real),
                                    "racerlab": disparity(rendered[:64])}
        line["load_avg"] = round(os.getloadavg()[0], 2)
        print(json.dumps(line), flush=True)
        for k, i in match.items():
            pairs.append((k, eyes[k], cand[i, ..., 0]))
            if stereo:  # the right eyes beside each other too
                right = k.removesuffix("_left") + "_right"
                pairs.append((right, real[right], cand[i, ..., 1]))
    if args.png:
        picture(pairs, args.png)


if __name__ == "__main__":
    main()
