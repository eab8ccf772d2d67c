"""docs/car.md's two pictures of the built-in cars: the droa car against the DRoA 2026 logs, and a track's line and
limit.

    python benchmarks/car_pictures.py                       # docs/img/car_droa.png and docs/img/limit_reinvent2019.png
    python benchmarks/car_pictures.py --out /tmp/pictures   # somewhere else

car_droa.png: `racerlab calibrate`'s picture (`calibrate.plot_fit`) of the built-in droa car (spec.CAR_TABLE, as
`benchmarks/car_fidelity.py --fit` fitted it: no refit here) on the held-out episodes of the DRoA 2026 training and
evaluation logs, their steps read by DRoA's timing rule. limit_reinvent2019.png: reInvent2019_track with the droa
car's racing line (the whole car 0.1 m inside) and its theoretical limit (`line.theoretical_limit`), and how far
outside the borders the off-track rule lets the base point go.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from racerlab.calibrate import constant_velocity_errors, errors, learned_floor, load_stretches, medians
from racerlab.calibrate.data import concat, split
from racerlab.calibrate.fit import Fit
from racerlab.calibrate.plot import plot_fit
from racerlab.line import racing_line, theoretical_limit
from racerlab.line.core import offtrack_overhang
from racerlab.sim.car import log_timing
from racerlab.spec import CAR_SPREAD, car_params
from racerlab.track import load_file

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
DROA_LOGS = ("reference/simtraces/droa2026-v6-Spain_track", "reference/simtraces/droa2026-v6-Spain_track-evaluation")


def droa_picture(path: Path) -> Path:
    car = car_params("droa", "5")
    parts = [split(load_stretches([SHARED / p], None, log_timing(car))) for p in DROA_LOGS]
    fit_st, held = concat([p[0] for p in parts]), concat([p[1] for p in parts])
    fit = Fit(car, dict(CAR_SPREAD[("droa", "velocity")]), medians(errors(held, car)),
              medians(constant_velocity_errors(held)), learned_floor(fit_st, held, car), len(fit_st), len(held), held)
    return plot_fit(fit, path)


def _offset(loop: np.ndarray, d: float, outward_of: np.ndarray) -> np.ndarray:
    """`loop` moved `d` metres along its normals, away from the points `outward_of` (the other border)."""
    t = np.roll(loop, -1, axis=0) - np.roll(loop, 1, axis=0)
    n = np.column_stack([-t[:, 1], t[:, 0]]) / np.maximum(np.hypot(t[:, 0], t[:, 1]), 1e-12)[:, None]
    centre = outward_of.mean(axis=0) if len(outward_of) else loop.mean(axis=0)
    away = np.sign(np.sum((loop - centre) * n, axis=1, keepdims=True))
    return loop + d * n * np.where(away == 0, 1.0, away)


def limit_picture(path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from racerlab.track.plot import draw_track

    track = load_file(SHARED / "tracks" / "reInvent2019_track.npy")
    car = car_params("droa", "5")
    line = racing_line(track, car=car)
    limit = theoretical_limit(track, car=car)
    reach = offtrack_overhang(car)
    fig, ax = plt.subplots(figsize=(10, 6.2))
    draw_track(track, ax=ax, waypoint_numbers=False, center_line=False, title=False, legend=False)
    centre = track.center.mean(axis=0)
    outer = _offset(track.outer, reach, centre[None, :])
    inner = _offset(track.inner, -reach, centre[None, :])
    for k, b in enumerate((outer, inner)):
        b = np.vstack([b, b[:1]])
        ax.plot(b[:, 0], b[:, 1], ":", color="tab:red", lw=0.8,
                label=f"base point's reach under the off-track rule ({reach:.3f} m out)" if k == 0 else None)
    for ln, colour, label in ((line, "tab:blue", f"racing line (whole car 0.1 m inside): {line.lap_time:.3f} s"),
                              (limit, "tab:red", f"limit ({limit.method}): {limit.lap_time:.3f} s")):
        xy = np.vstack([ln.xy, ln.xy[:1]])
        ax.plot(xy[:, 0], xy[:, 1], "-", color=colour, lw=1.8, label=label, zorder=7)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title(f"{track.name}, droa car (version 5): the racing line and the theoretical limit (standing laps)")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.02), frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img", help="the folder the pictures go to")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    print(droa_picture(args.out / "car_droa.png"))
    print(limit_picture(args.out / "limit_reinvent2019.png"))


if __name__ == "__main__":
    main()
