"""racerlab's own tracks, designed here and made with the generator (so they pass its checks).

Each design is a polygon in metres whose corners are rounded off by circular bends (see
`racerlab.track.generate.from_polygon`). The `.npy` files in `racerlab/data/tracks/` are what
`build` produces; regenerate them after changing a design with

    python -m racerlab.track.bundled            # writes src/racerlab/data/tracks/lab_*.npy

and a test checks that the stored files still equal what `build` gives.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from racerlab.track.core import Track
from racerlab.track.generate import from_polygon
from racerlab.track.registry import BUNDLED_DIR


@dataclass(frozen=True)
class Design:
    """A bundled track: polygon corners (m, counter-clockwise), the bend radius at each, and the targets."""

    corners: tuple[tuple[float, float], ...]
    radii: tuple[float, ...]
    width: float
    length: float
    min_radius: float = 0.6
    start: float | None = None  # edge index + fraction along its straight; None = longest straight
    about: str = ""


DESIGNS: dict[str, Design] = {
    "lab_oval": Design(
        corners=((0.0, 0.0), (5.79, 0.0), (5.79, 3.0), (0.0, 3.0)),
        radii=(1.5, 1.5, 1.5, 1.5),
        width=1.07, length=15.0, start=0.3,
        about="an easy stadium oval: two straights joined by two half circles of 1.5 m radius",
    ),
    "lab_technical": Design(
        corners=((-0.3, 0.0), (5.4, 0.0), (5.4, 1.5), (3.5, 1.5), (3.5, 3.4), (2.35, 3.4), (1.8, 4.2),
                 (0.0, 4.2), (-0.9, 1.6)),
        radii=(1.1, 0.75, 0.75, 0.75, 0.7, 0.6, 0.6, 1.0, 1.2),
        width=0.76, length=18.0, start=0.25,
        about="the default: a main straight into a hairpin, esses, a chicane and three sweepers",
    ),
    "lab_grand_prix": Design(
        corners=((0.3, 0.0), (10.0, 0.0), (10.0, 5.5), (8.3, 5.5), (8.3, 2.5), (5.6, 2.5), (4.6, 4.2),
                 (0.8, 4.2), (-1.3, 2.6)),
        radii=(1.6, 1.6, 0.85, 0.85, 0.8, 1.0, 1.0, 1.3, 1.3),
        width=1.07, length=35.0, start=0.2,
        about="a long circuit: a 7 m main straight, a fast sweeper, a hairpin, esses and a back straight",
    ),
}


def build(name: str) -> Track:
    """The bundled track `name` as the generator makes it from its design."""
    d = DESIGNS[name]
    return from_polygon(d.corners, d.radii, width=d.width, length=d.length, name=name,
                        min_radius=d.min_radius, start=d.start)


def write_all(folder: Path = BUNDLED_DIR) -> list[Path]:
    """Regenerate every bundled track file in `folder`; returns the paths written."""
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for name in DESIGNS:
        path = folder / f"{name}.npy"
        np.save(path, build(name).as_array())
        out.append(path)
    return out


if __name__ == "__main__":  # pragma: no cover
    for p in write_all(Path(sys.argv[1]) if len(sys.argv) > 1 else BUNDLED_DIR):
        print(p)
