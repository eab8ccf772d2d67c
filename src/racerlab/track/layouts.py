"""Track layouts: which tracks are one shape, and sets of tracks drawn one per layout.

A *layout* is a track's shape, whatever its name or direction: a track's `_cw` / `_ccw` files, copies under
another name (Monaco and Monaco_building), copies moved elsewhere (2022_summit_speedway and
2024_reinvent_champ) and mirror images (reInvent2019_wide and reInvent2019_wide_mirrored) are one layout
(`same_layout`: their centre lines, centred, lie within `LAYOUT_TOL_M` of each other on average, either way
mirrored or not). Held-out tracks (`held_out_tracks`) are drawn only from layouts a model never trained on, and a
training set (`training_tracks`) only from layouts outside a held-out set.

    >>> held = held_out_tracks("aws-tracks/", 20, seed=0)      # 20 layouts, one file each
    >>> train = training_tracks("aws-tracks/", held)            # one file per every other layout
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from racerlab.errors import RacerlabError, TrackError
from racerlab.track.core import Track, load_file

DIRECTION_SUFFIX = re.compile(r"_(ccw|cw)$")
# Two AWS centre lines of one layout lie within 0.01 m of each other (centred); the closest distinct layouts,
# small ovals of ~20 m, 0.24 m apart (Mexico_track and Tokyo_Training_track mirrored); reinvent_base and its
# wider redraw reInvent2019_wide 0.17 m, counted as one layout
LAYOUT_TOL_M = 0.2
LAYOUT_POINTS = 300  # centre-line points compared


class Layout:
    """A track's layout: `LAYOUT_POINTS` points evenly spaced along its centre line, centred on their mean (with
    their nearest-neighbour trees, built once)."""

    FLIPS = ((1.0, 1.0), (-1.0, 1.0), (1.0, -1.0))  # as it is, mirrored left-right, mirrored top-bottom

    def __init__(self, track):
        c = np.asarray(track.center, dtype=np.float64)
        if len(c) > 1 and np.allclose(c[0], c[-1]):
            c = c[:-1]
        ring = np.vstack([c, c[:1]])
        s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(ring, axis=0).T))])
        u = np.linspace(0.0, s[-1], LAYOUT_POINTS, endpoint=False)
        pts = np.stack([np.interp(u, s, ring[:, 0]), np.interp(u, s, ring[:, 1])], axis=1)
        self.points = pts - pts.mean(axis=0)
        self.lo, self.hi = self.points.min(axis=0), self.points.max(axis=0)
        self.radius = np.hypot(*self.points.T)
        self.rmin, self.rmax = float(self.radius.min()), float(self.radius.max())
        self._trees = None

    def trees(self):
        if self._trees is None:
            from scipy.spatial import cKDTree

            self._trees = [cKDTree(self.points * flip) for flip in self.FLIPS]
        return self._trees

    def gap(self, other: Layout, flip: int = 0) -> float:
        """Mean distance from each point of this layout to the nearest of `other` (mirrored by FLIPS[flip]),
        and back, averaged."""
        mine, theirs = self.trees()[0], other.trees()[flip]
        return 0.5 * (float(theirs.query(self.points)[0].mean()) +
                      float(mine.query(other.points * self.FLIPS[flip])[0].mean()))

    def near(self, other: Layout, flip: int, tol: float) -> bool:
        """gap(other, flip) < tol. A lower bound rules most pairs out first: no point is nearer to a layout than to
        its bounding box, nor than to the ring between its least and greatest distance from its centre."""
        if 0.5 * (self._outside(other, flip) + other._outside(self, flip)) >= tol:
            return False
        return self.gap(other, flip) < tol

    def _outside(self, other: Layout, flip: int) -> float:
        """Mean over this layout's points of a lower bound on their distance to `other` mirrored by FLIPS[flip]."""
        pts = self.points * self.FLIPS[flip]  # mirroring both alike keeps every distance
        box = np.hypot(*np.maximum(np.maximum(other.lo - pts, pts - other.hi), 0.0).T)
        ring = np.maximum(np.maximum(other.rmin - self.radius, self.radius - other.rmax), 0.0)
        return float(np.maximum(box, ring).mean())


def layout_shape(track) -> Layout:
    """`track`'s `Layout`."""
    return Layout(track)


def same_layout(a: Layout, b: Layout, tol: float = LAYOUT_TOL_M) -> bool:
    """Whether two layouts are one: the same shape, or its mirror image (either axis), wherever it lies and
    whichever way it is driven."""
    return any(a.near(b, k, tol) for k in range(len(Layout.FLIPS)))


def folder_layouts(folder) -> dict[str, Path]:
    """One `.npy` file per track name of `folder`, its `_cw` / `_ccw` variants folded in (the plain file, else
    the first variant)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RacerlabError(f"{folder}: no such folder of track .npy files; give a folder that holds AWS tracks "
                            "(`racerlab tracks fetch --all` writes them)")
    layouts: dict[str, Path] = {}
    for p in sorted(folder.glob("*.npy")):
        base = DIRECTION_SUFFIX.sub("", p.stem)
        if base not in layouts or p.stem == base:
            layouts[base] = p
    return layouts


def _excluded_shapes(exclude, layouts: dict[str, Path]) -> list[Layout]:
    """The layouts of `exclude` (tracks, paths or names: a name of the folder, else any track racerlab loads)."""
    from racerlab import track as tracks

    shapes = []
    for e in exclude:
        if isinstance(e, Track):
            shapes.append(layout_shape(e))
            continue
        path, base = Path(str(e)), DIRECTION_SUFFIX.sub("", Path(str(e)).stem)
        if path.is_file():
            t = load_file(path)
        elif base in layouts:
            t = load_file(layouts[base])
        else:
            try:
                t = tracks.load(str(e))
            except TrackError as exc:
                raise RacerlabError(f"{e}: a training track that does not load ({exc}); held-out tracks must be "
                                    "checked against every track trained on") from None
        shapes.append(layout_shape(t))
    return shapes


def held_out_tracks(folder, count: int = 20, exclude=(), seed: int = 0) -> list[Path]:
    """`count` track files (.npy) of `folder` chosen at random (seeded), one per layout (`same_layout`), none of
    the layout of a track in `exclude` (the training tracks: names, paths or tracks), none open (no lap to
    complete). Fewer than `count` is an error that says how many there are."""
    layouts = folder_layouts(folder)
    banned = _excluded_shapes(exclude, layouts)
    names = sorted(layouts)
    picked, shapes = [], []
    for i in np.random.default_rng(seed).permutation(len(names)).tolist():
        if len(picked) == count:
            break
        t = load_file(layouts[names[i]])
        if not t.closed:
            continue
        shape = layout_shape(t)
        if not any(same_layout(shape, other) for other in (*banned, *shapes)):
            shapes.append(shape)
            picked.append(i)
    if len(picked) < count:
        raise RacerlabError(f"{folder}: {len(picked)} closed track layouts not excluded, fewer than the {count} "
                            "asked; lower --count or add tracks")
    return [layouts[names[i]] for i in sorted(picked)]


def training_tracks(folder, held_out, count: int | None = None, seed: int = 0) -> list[Path]:
    """Track files of `folder` to train on: one per closed layout that is not the layout of any track in
    `held_out` (paths, names or tracks), all of them or `count` chosen at random (seeded), in name order."""
    layouts = folder_layouts(folder)
    banned = _excluded_shapes(held_out, layouts)
    kept, shapes = [], []
    for name in sorted(layouts):
        t = load_file(layouts[name])
        shape = layout_shape(t) if t.closed else None
        if shape is None or any(same_layout(shape, other) for other in (*banned, *shapes)):
            continue
        shapes.append(shape)
        kept.append(layouts[name])
    if count is not None and count < len(kept):
        idx = np.random.default_rng(seed).choice(len(kept), size=count, replace=False)
        kept = [kept[i] for i in sorted(idx.tolist())]
    return kept
