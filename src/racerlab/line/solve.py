"""Racing-line solvers: minimum curvature and shortest path, as bounded linear least squares over
lateral offsets, re-linearised until converged.

Both start from the centre line resampled every ~`step_m` metres. One iteration moves each point
along its normal by an offset α_i kept inside [lo_i, hi_i] (the room to the borders minus the car's
half width, its wheels and the margin) and minimises

* minimum curvature: Σ (n_i·(p_{i-1} - 2 p_i + p_{i+1}))² / h⁴, the squared signed curvature of an
  evenly spaced path (TUMFTM's `mincurv` objective, without their spline machinery);
* shortest path: Σ |p_{i+1} - p_i|² / h², which for evenly spaced points is L²/M.

Both are exact only while the points stay evenly spaced and the normals stay those of the
reference, so the solution is resampled evenly, becomes the new reference, and the problem is
solved again (TUMFTM's `mincurv_iqp` idea), with Levenberg-Marquardt damping, until no step larger
than `tol_m` improves the line. Each step is a bounded QP solved exactly (`box_qp`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from racerlab.errors import TrackError
from racerlab.line import geometry as G
from racerlab.track import Track

METHODS = ("mincurv", "shortest")
CUSHION_M = 5e-3  # extra clearance in the bounds for the spline's bulge between points
GROWN_CLEARANCE_M = 0.1  # a negative clearance keeps this much to borders grown by it and the overhang (as the
# line's own clearance does: a band only a few cm thick could be crossed by one step's bulge between points)


class Solution(NamedTuple):
    xy: np.ndarray  # (M, 2) closed loop without the repeated point, starting abreast of the start line
    iterations: int
    converged: bool
    last_move_m: float  # largest free offset (beyond what the bounds force) of the last iteration


def _difference_matrix(m: int, order: int, closed: bool) -> sp.csr_matrix:
    """First (p_{i+1} - p_i) or second (p_{i-1} - 2 p_i + p_{i+1}) differences; cyclic for a loop."""
    if closed:
        eye = sp.identity(m, format="csr")
        shift = sp.csr_matrix((np.ones(m), (np.arange(m), np.mod(np.arange(m) + 1, m))), shape=(m, m))
        return shift - eye if order == 1 else shift + shift.T - 2.0 * eye
    if order == 1:
        return sp.diags([-np.ones(m - 1), np.ones(m - 1)], [0, 1], shape=(m - 1, m), format="csr")
    return sp.diags([np.ones(m - 2), -2.0 * np.ones(m - 2), np.ones(m - 2)], [0, 1, 2], shape=(m - 2, m),
                    format="csr")


def _weights(method: str, blend: float | None) -> dict[str, float]:
    """What each method's objective weighs: one method alone, or with `blend` = w the minimum-curvature one
    × (1 - w) and the shortest-path one × w, each scaled by its Hessian's typical diagonal (6/h⁴, 2/h²) so that w
    runs from one line to the other."""
    return {method: 1.0} if blend is None else {"mincurv": 1.0 - blend, "shortest": blend}


def _scale(method: str, h: float) -> float:
    return h**4 / 6.0 if method == "mincurv" else h**2 / 2.0


def offsets(ref: np.ndarray, normal: np.ndarray, lo: np.ndarray, hi: np.ndarray, method: str,
            closed: bool = True, damping: float = 0.0, blend: float | None = None) -> np.ndarray:
    """The bounded least-squares step: lateral offsets α (M,) for one linearisation.

    `damping` adds damping × (mean diagonal) × |α|² to the objective (a Levenberg-Marquardt step); `blend`
    mixes both methods' objectives (`_weights`).

    Minimum curvature keeps only the normal component of each second difference, n_i·(p_{i-1} -
    2 p_i + p_{i+1}) / h² (the signed curvature of evenly spaced points): the tangential component
    only says how unevenly the points are spaced, which the resampling fixes anyway, and
    minimising it too makes the offsets fight the resampling (the line then circles a few cm
    around the optimum without settling). As in TUMFTM's formulation the spacing h is the
    reference's, so a wider arc is not counted as a straighter one: the objective keeps a pull
    toward shorter lines. That is what makes the line fast: on a ring it is the inner circle,
    which under a grip limit is also the quickest (lap time 2π·√(r/grip) grows with r); the exact
    ∫κ² ds would send it round the outside, 9 % slower on reInvent2019_track.
    """
    m = len(ref)
    h = float(G.arc_length(ref, closed)[-1]) / (m if closed else m - 1)
    hess, grad = sp.csc_matrix((m, m)), np.zeros(m)
    for name, weight in _weights(method, blend).items():
        if weight <= 0:
            continue
        a, b = _least_squares(ref, normal, name, closed, h)
        f = weight * (_scale(name, h) if blend is not None else 1.0)
        hess, grad = hess + f * (a.T @ a), grad - f * (a.T @ b)
    hess = hess.tocsc()
    if damping > 0:
        hess = hess + damping * float(hess.diagonal().mean()) * sp.identity(m, format="csc")
    return box_qp(hess, grad, lo, hi)


def _least_squares(ref, normal, method: str, closed: bool, h: float):
    """(A, b) of one method's objective |A α - b|² over the offsets α."""
    m = len(ref)
    nx, ny = sp.diags(normal[:, 0]), sp.diags(normal[:, 1])
    if method == "mincurv":
        d = _difference_matrix(m, 2, closed) / h**2
        rows = normal if closed else normal[1:-1]  # the point each second difference is centred on
        px, py = sp.diags(rows[:, 0]), sp.diags(rows[:, 1])
        a = (px @ d @ nx + py @ d @ ny).tocsr()
        return a, -(rows[:, 0] * (d @ ref[:, 0]) + rows[:, 1] * (d @ ref[:, 1]))
    d = _difference_matrix(m, 1, closed) / h
    return sp.vstack([d @ nx, d @ ny]).tocsr(), -np.concatenate([d @ ref[:, 0], d @ ref[:, 1]])


def box_qp(hess: sp.csc_matrix, grad0: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_iter: int = 200,
           tol: float = 1e-8) -> np.ndarray:
    """min ½ xᵀHx + gᵀx subject to lo ≤ x ≤ hi, for sparse positive (semi-)definite H.

    Projected Newton (Bertsekas 1982): the variables at a bound whose gradient pushes outward are
    held, a Newton step is taken in the others, and the step is projected onto the box and halved
    until the objective falls enough (Armijo). Once the right bounds are held one full step lands
    on the minimum, so a handful of sparse solves is enough; unlike the primal-dual active-set
    method, it cannot cycle on this non-M-matrix Hessian (fourth differences), and unlike
    `lsq_linear` it does not stall on its bad conditioning. Stops when a step moves no variable by
    more than `tol` (m).
    """
    n = len(grad0)
    ridge = 1e-9 * float(np.abs(hess.diagonal()).max())
    hess = (hess + ridge * sp.identity(n, format="csc")).tocsc()
    x = np.clip(np.zeros(n), lo, hi)
    for _ in range(max_iter):
        g = hess @ x + grad0
        room = np.minimum(np.abs(x - np.clip(x - g, lo, hi)).max(), 1e-6)
        held = ((x <= lo + room) & (g > 0)) | ((x >= hi - room) & (g < 0))
        free = sp.diags((~held).astype(np.float64))
        newton = (free @ hess @ free + sp.diags(held.astype(np.float64))).tocsc()
        d = spla.spsolve(newton, -np.where(held, 0.0, g))
        x_new = _armijo(hess, grad0, x, g, d, lo, hi)
        step = float(np.abs(x_new - x).max())
        x = x_new
        if step < tol:
            break
    return x


def _armijo(hess, grad0, x, g, d, lo, hi, sigma: float = 1e-4) -> np.ndarray:
    """The projected point x + t·d, t = 1, ½, ¼, ... that lowers the objective by σ·gᵀ(x - x_t)."""
    f0 = 0.5 * x @ (hess @ x) + grad0 @ x
    t = 1.0
    for _ in range(40):
        xt = np.clip(x + t * d, lo, hi)
        if 0.5 * xt @ (hess @ xt) + grad0 @ xt <= f0 + sigma * (g @ (xt - x)):
            return xt
        t *= 0.5
    return x


def solve(track: Track, clearance: float, method: str = "mincurv", step_m: float = 0.1, tol_m: float = 5e-3,
          max_iter: int = 40, blend: float | None = None) -> Solution:
    """Re-linearised bounded least squares until no step larger than `tol_m` improves the line (moves
    that only bring a point back inside its bounds do not count) and every point keeps `clearance`
    to the borders. Raises `TrackError` where the road is narrower than
    2 × clearance.

    Each step is checked on the real objective of the resampled line (∫κ² ds or the length). A step
    that makes it worse is refused and the next one is damped (Levenberg-Marquardt: a penalty on
    the offsets, raised ×4 per refusal and lowered after a success): on long, smooth bends the
    objective is nearly flat and the full linearised step swings the line a few cm to and fro.
    The bounds carry a small cushion (`CUSHION_M`) because the spline through the new points
    bulges a few millimetres past them in tight corners; where it still falls short, the clearance
    there grows and the solve goes on from the line it has.

    A negative `clearance` lets the point leave the road by up to -clearance (the limit under the simulator's
    off-track rule, `line.core.offtrack_overhang`): the borders are grown by that much
    (`geometry.grown_border_segments`). `blend` (0-1) solves for a mix of both methods' objectives (`_weights`).
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    closed = track.closed
    centre = track.center[:-1] if closed else track.center
    m = max(int(round(track.length / step_m)), 8)
    ref = G.resample_polyline(centre, m, closed)
    overhang = max(-clearance, 0.0)
    if overhang > 0:  # the point may leave the road by up to -clearance: keep a small clearance to grown borders
        segs = G.grown_border_segments(track, GROWN_CLEARANCE_M + overhang)
        clearance = GROWN_CLEARANCE_M
    else:
        segs = G.border_segments(track)
    reach = float(track.widths.max()) + 2.0 * overhang
    extra = np.full(m, CUSHION_M)  # clearance added to what the car needs
    grown = GROWN_CLEARANCE_M + overhang if overhang > 0 else 0.0
    best, damping, move, it = np.inf, 0.0, np.inf, 0  # best = inf: the next step is taken whatever it gives
    for it in range(1, max_iter + 1):
        normal = G.left_normals(ref, closed)
        lo, hi = _room(track, ref, normal, segs, clearance + extra, (reach, grown))
        alpha = offsets(ref, normal, lo, hi, method, closed, damping, blend)
        move = float(np.abs(alpha - np.clip(0.0, lo, hi)).max())  # beyond what the bounds force
        if move < tol_m:
            short = _shortfall(ref, segs, clearance, closed)
            if not short.any():
                return Solution(ref, it, True, move)
            extra += short + 2e-3
            best, damping = np.inf, 0.0
            continue
        cand = _resample(track, ref + alpha[:, None] * normal, m, closed)
        value = objective(cand, method, closed, blend)
        if value <= best:
            ref, best, damping = cand, value, damping / 4.0
        else:
            damping = max(4.0 * damping, 1e-3)
    return Solution(ref, it, False, move)


def objective(xy: np.ndarray, method: str, closed: bool = True, blend: float | None = None) -> float:
    """What a method minimises: ∫κ² ds (1/m) for minimum curvature, the length (m) for the shortest path; with
    `blend` the mix the steps minimise, (1 - w)·h⁴/6·Σκ² + w/2·Σ|p_{i+1} - p_i|²."""
    s = G.arc_length(xy, closed)
    h = float(s[-1]) / (len(xy) if closed else len(xy) - 1)
    if blend is not None:
        k2 = float(np.sum(G.menger_curvature(xy, closed) ** 2))
        steps = np.diff(np.vstack([xy, xy[:1]]) if closed else xy, axis=0)
        return (1.0 - blend) * _scale("mincurv", h) * k2 + blend * 0.5 * float(np.sum(steps**2))
    if method == "shortest":
        return float(s[-1])
    return float(np.sum(G.menger_curvature(xy, closed) ** 2) * h)


def _resample(track: Track, xy: np.ndarray, m: int, closed: bool) -> np.ndarray:
    return G.resample_smooth(xy, m, closed, start=track.center[0] if closed else None)


def _room(track: Track, ref, normal, segs, clearance, reach_grown: tuple[float, float]):
    """`G.lateral_room` of each point (borders grown by `grown` m); a point with none raises `TrackError`, which
    says the road is too narrow only where it is."""
    reach, grown = reach_grown
    lo, hi = G.lateral_room(ref, normal, *segs, clearance, reach)
    if np.any(lo > hi):
        i = int(np.argmax(lo - hi))
        where = track.project([ref[i]])
        need = 2.0 * (float(np.broadcast_to(clearance, lo.shape)[i]) - grown)
        width, at = float(where.width[0]), f"{float(where.s[0]):.1f} m from the start"
        if width > need + 0.01:
            raise TrackError(f"{track.name}: the line finds no room {at}, though the road there is {width:.2f} m wide "
                             f"and the car needs {max(need, 0.0):.2f} m: its borders fold or cross there; check them "
                             f"with `racerlab tracks show {track.name}`")
        raise TrackError(f"{track.name}: the road is {width:.2f} m wide {at}, too narrow for the car and the margin "
                         f"(they need {need:.2f} m); use a smaller margin (--margin)")
    return lo, hi


def _shortfall(xy: np.ndarray, segs, clearance: float, closed: bool) -> np.ndarray:
    """How much clearance each point and the chords to its neighbours lack, m (0 where enough).

    The chords are checked at their quarter points: a car drives the chord, and near a sharp
    corner of a border the middle of a 10 cm chord is not always its closest point.
    """
    nxt = np.roll(xy, -1, axis=0) if closed else np.vstack([xy[1:], xy[-1:]])
    d_pt = G.border_distance(xy, *segs)
    d_seg = np.min([G.border_distance(xy + f * (nxt - xy), *segs) for f in (0.25, 0.5, 0.75)], axis=0)
    before = np.roll(d_seg, 1) if closed else np.concatenate([d_seg[:1], d_seg[:-1]])
    d = np.minimum(d_pt, np.minimum(d_seg, before))
    return np.maximum(clearance - 5e-4 - d, 0.0)
