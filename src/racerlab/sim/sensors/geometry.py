"""Where the sensors sit on the car and what each camera pixel looks at (facts §4).

All numbers come from the AWS car description (`deepracer_single_cam.urdf`, `racecar.gazebo`):
the chassis is 0.023249 m above `base_link`; the camera's `zed_camera_joint` is at chassis +
(0.0917, 0, 0.08) pitched 0.2618 rad down, and the optical frame (`camera_joint`) sits a further
(0.0448, 0, 0.04) along that tilted frame, which puts it 0.1453 m ahead of and 0.1303 m above the
base origin. The lidar (`hokuyo_joint`) is at chassis + (0.029, 0, 0.161), turned by yaw π. The AWS
simulator's frames show the ground as from a camera 0.163 m up, though, and the AWS look renders from there
(`look.TrackLook.camera_height_m`); the classic look keeps the URDF's height.

Because the car neither rolls nor pitches in racerlab, every pixel looks at a fixed point of the
ground *in the car's frame*, and, the camera having no roll, every image row looks at a straight
ground line across the car at one distance ahead: the ground point moves by the same step from
column to column, and the pixel's footprint (how much ground it sees) is the same along the row.
`RowPlan` works out once per camera which ground lines each row samples (several for distant rows,
whose pixels stretch far along the ground), at which raster level, and how much haze and sky
each row holds; rendering a frame then only rotates those lines into the world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

CHASSIS_Z_M = 0.023249
ZED_XYZ_M = (0.0917, 0.0, 0.0800)
CAMERA_IN_ZED_M = (0.0448, 0.0, 0.04)
CAMERA_PITCH_RAD = 0.2618
CAMERA_HFOV_RAD = 1.13
AWS_CAMERA_HEIGHT_M = 0.163  # where the AWS simulator's frames show the camera, not the URDF's 0.130 m (look.py)
STEREO_HALF_BASELINE_M = 0.03
IMAGE_H, IMAGE_W = 120, 160

LIDAR_XYZ_M = (0.029, 0.0, 0.161)  # from the chassis
LIDAR_YAW_RAD = math.pi
LIDAR_MIN_ANGLE_RAD, LIDAR_MAX_ANGLE_RAD = -2.61799, 2.61799
LIDAR_RAYS = 64

GROUND_MAX_M = 30.0  # ground further than this ahead is drawn in the haze colour
HAZE_NEAR_M, HAZE_FAR_M = 4.0, 30.0  # the ground fades into haze between these distances
ANISOTROPY = 4.0  # a sample may stretch this much more along the view than across it
MAX_SUBROWS = 3
LEVEL_BIAS = -0.5  # + blurrier, - sharper (more shimmer): the raster level is floor(log2(footprint / texel) + bias)
COLUMN_STEP_TEXELS = 0.75  # read every 2nd / 4th column where that many columns span less than this
FINE_MIN_GAIN = 0.3  # the fine grain is left out of rows that would show less than this share of it
SKY_EL_STEP_RAD = math.radians(0.25)
SKY_AZ_BINS = 1024


def camera_position() -> tuple[float, float]:
    """(x ahead, z up) of the optical frame from the base origin, from the URDF joints."""
    c, s = math.cos(CAMERA_PITCH_RAD), math.sin(CAMERA_PITCH_RAD)
    dx, _, dz = CAMERA_IN_ZED_M
    x = ZED_XYZ_M[0] + dx * c + dz * s
    z = CHASSIS_Z_M + ZED_XYZ_M[2] - dx * s + dz * c
    return x, z


def lidar_position() -> float:
    """x ahead of the base origin of the lidar's centre (it is on the car's axis)."""
    return LIDAR_XYZ_M[0]


def lidar_ray_angles() -> np.ndarray:
    """(64,) ray directions in the car frame, rad, in the order of the AWS scan.

    The scan runs from −150° to +150° in the laser frame, which is turned by π: ray 0 looks 30°
    left of straight ahead, the sweep passes the left side, the rear (ray 31/32) and the right, and
    ray 63 looks 30° right of ahead. The 60° gap is in front, where the camera looks.
    """
    a = np.linspace(LIDAR_MIN_ANGLE_RAD, LIDAR_MAX_ANGLE_RAD, LIDAR_RAYS) + LIDAR_YAW_RAD
    return np.mod(a + math.pi, 2 * math.pi) - math.pi


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera: AWS's 640×480 Gazebo camera as seen after the resize to 160×120."""

    width: int = IMAGE_W
    height: int = IMAGE_H
    hfov_rad: float = CAMERA_HFOV_RAD
    pitch_rad: float = CAMERA_PITCH_RAD

    @property
    def focal_px(self) -> float:
        return 0.5 * self.width / math.tan(0.5 * self.hfov_rad)

    def rays(self, du=0.0, dv=0.0) -> np.ndarray:
        """(H, W, 3) ray directions in the car frame (x ahead, y left, z up) through pixel centres + (du, dv) px
        (scalars, or arrays that broadcast against (H, W))."""
        f = self.focal_px
        uu = (np.arange(self.width)[None, :] + 0.5 + du - 0.5 * self.width) / f  # right
        vv = (np.arange(self.height)[:, None] + 0.5 + dv - 0.5 * self.height) / f  # down
        uu, vv = np.broadcast_arrays(uu, vv)
        c, s = math.cos(self.pitch_rad), math.sin(self.pitch_rad)
        return np.stack([c - vv * s, -uu, -s - vv * c], axis=-1)

    def project(self, points_car: np.ndarray, cam_xyz) -> np.ndarray:
        """Pixel (col, row) coordinates, continuous, of car-frame points seen from a camera at `cam_xyz`."""
        p = np.asarray(points_car, dtype=np.float64) - np.asarray(cam_xyz, dtype=np.float64)
        c, s = math.cos(self.pitch_rad), math.sin(self.pitch_rad)
        fwd = p[..., 0] * c - p[..., 2] * s
        down = -p[..., 0] * s - p[..., 2] * c
        right = -p[..., 1]
        f = self.focal_px
        return np.stack([right / fwd * f + 0.5 * self.width, down / fwd * f + 0.5 * self.height], axis=-1)


    @property
    def horizon_v(self) -> float:
        """Image row coordinate (continuous, 0 = top edge) of the horizon."""
        return 0.5 * self.height - self.focal_px * math.tan(self.pitch_rad)

    def ground_line(self, v, cam_z: float) -> tuple[np.ndarray, np.ndarray]:
        """For image row coordinates `v` below the horizon: the ground line's distance ahead of the camera's
        foot point and its lateral step per column (negative: columns run to the car's right), m."""
        vn = (np.asarray(v, dtype=np.float64) - 0.5 * self.height) / self.focal_px
        c, s = math.cos(self.pitch_rad), math.sin(self.pitch_rad)
        drop = s + vn * c
        t = np.where(drop > 1e-12, cam_z / np.maximum(drop, 1e-12), np.inf)
        return t * (c - vn * s), -t / self.focal_px


class RowPlan:
    """What each image row of one camera samples (see the module docstring); arrays for the renderer.

    Ground lines ("sub-rows", S of them, grouped by image row through `row_first`): `sub_x` the
    distance ahead of the camera's foot point, `sub_y0` the lateral offset of column 0 (+ left),
    `sub_dy` the lateral step per column, `sub_level` the raster level matching the footprint,
    `sub_step` 1, 2 or 4: read every step-th column and interpolate (where texels span several
    pixels; the same for all lines of a row), `sub_weight` its share of the pixel after haze.
    Per row: `row_haze` the share of haze colour, `row_sky` the share above the horizon, whose
    pixels read the background panorama at `sky_el` (row index) and `sky_az` (azimuth in
    panorama columns, car frame, + left). For a grainy look, `sub_fine`: the share of the fine grain
    each ground line shows; for walls, `edge_dir`: the rays through the rows' pixel edges.
    """

    def __init__(self, model: CameraModel, cam_z: float, cell_m: float, num_levels: int, filter_px: float, *,
                 anisotropy: float = ANISOTROPY, max_subrows: int = MAX_SUBROWS, level_bias: float = LEVEL_BIAS,
                 haze_m: tuple | None = (HAZE_NEAR_M, HAZE_FAR_M), fine_cell_m: float = 0.0):
        self.model = model
        self.cam_z = float(cam_z)
        self.haze_m = haze_m
        self.filter_px = float(filter_px)
        self.fine_cell_m = float(fine_cell_m)
        self.anisotropy, self.max_subrows, self.level_bias = float(anisotropy), int(max_subrows), float(level_bias)
        h = model.height
        subs: list[tuple[int, float, float, float, int, int, float]] = []
        self.row_first = np.zeros(h + 1, dtype=np.int64)
        self.row_haze = np.zeros(h)
        self.row_sky = np.zeros(h)
        vh = model.horizon_v
        for r in range(h):
            self.row_first[r] = len(subs)
            top = max(float(r), vh)
            if top >= r + 1:
                self.row_sky[r] = 1.0
                continue
            self.row_sky[r] = top - r
            self.row_haze[r] = self._ground_row(r, top, cell_m, num_levels, filter_px, subs)
        self.row_first[h] = len(subs)
        arr = np.array(subs, dtype=np.float64).reshape(-1, 7)
        self.sub_row = arr[:, 0].astype(np.int64)
        self.sub_x, self.sub_y0, self.sub_dy = arr[:, 1].copy(), arr[:, 2].copy(), arr[:, 3].copy()
        self.sub_level = arr[:, 4].astype(np.int64)
        self.sub_step = arr[:, 5].astype(np.int64)
        for r in range(h):  # a row's lines share its finest column step (the renderer fills in once per row)
            a, b = self.row_first[r], self.row_first[r + 1]
            if b > a:
                self.sub_step[a:b] = self.sub_step[a:b].min()
        self.sub_weight = arr[:, 6].copy()
        self._sky_tables()
        self._fine_gains()
        self.edge_dir = self._edge_rays()

    def _ground_row(self, r, top, cell_m, num_levels, filter_px, subs) -> float:
        """Append row r's ground lines (covering image rows top..r+1) to `subs`; return its haze share."""
        m, cz = self.model, self.cam_z
        share = r + 1 - top
        x_top, _ = m.ground_line(top, cz)
        x_bot, dy_bot = m.ground_line(r + 1.0, cz)
        extent = min(float(x_top), GROUND_MAX_M) - float(x_bot)
        n = int(np.clip(math.ceil(max(extent, 0.0) / (self.anisotropy * filter_px * abs(float(dy_bot)))), 1,
                        self.max_subrows))
        haze = 0.0
        for k in range(n):
            v0 = top + share * k / n
            v1 = top + share * (k + 1) / n
            x, dy = (float(a) for a in m.ground_line(0.5 * (v0 + v1), cz))
            if not x <= GROUND_MAX_M:
                haze += share / n
                continue
            along = float(m.ground_line(v0, cz)[0] - m.ground_line(v1, cz)[0])
            foot = max(filter_px * abs(dy), min(along, GROUND_MAX_M))
            level = int(np.clip(math.floor(math.log2(max(foot / cell_m, 1e-9)) + self.level_bias), 0, num_levels - 1))
            fade = 0.0 if self.haze_m is None else \
                float(np.clip((x - self.haze_m[0]) / (self.haze_m[1] - self.haze_m[0]), 0.0, 1.0)) ** 0.7
            y0 = dy * (0.5 - 0.5 * m.width)
            texels = abs(dy) / (cell_m * 2.0 ** level)
            step = 4 if 4 * texels <= COLUMN_STEP_TEXELS else 2 if 2 * texels <= COLUMN_STEP_TEXELS else 1
            subs.append((r, x, y0, dy, level, step, share / n * (1.0 - fade)))
            haze += share / n * fade
        return haze

    def _fine_gains(self) -> None:
        """`sub_fine`: how much of the fine grain (values `fine_cell_m` apart on the ground) each ground line shows.
        A pixel averages the grain over its footprint, which leaves 1 / sqrt(values covered) of it; lines read
        from coarser raster levels, or that would keep under FINE_MIN_GAIN of it, show none (the raster's texel
        noise stands in for it there, at no cost)."""
        self.sub_fine = np.zeros(self.sub_x.size)
        if self.fine_cell_m <= 0.0:
            return
        for j, r in enumerate(self.sub_row):
            if self.sub_level[j] == 0:
                across, along = self.footprint(int(r))
                gain = min(1.0, self.fine_cell_m / math.sqrt(across * along))
                self.sub_fine[j] = gain if gain >= FINE_MIN_GAIN else 0.0

    def footprint(self, r: int) -> tuple[float, float]:
        """Ground footprint of a pixel of image row r (below the horizon): across (filter width) and along, m."""
        m, cz = self.model, self.cam_z
        _, dy = m.ground_line(r + 0.5, cz)
        along = float(m.ground_line(r, cz)[0] - m.ground_line(r + 1.0, cz)[0])
        return self.filter_px * abs(float(dy)), max(along, 1e-9)

    def _edge_rays(self) -> np.ndarray:
        """(H + 1, W, 3) car-frame ray directions through the top edge of each image row (and the bottom edge of
        the last), at column centres: what the renderer intersects with the walls."""
        m = self.model
        f = m.focal_px
        uu = (np.arange(m.width) + 0.5 - 0.5 * m.width) / f
        vv = (np.arange(m.height + 1) - 0.5 * m.height) / f
        uu, vv = np.broadcast_arrays(uu[None, :], vv[:, None])
        c, s = math.cos(m.pitch_rad), math.sin(m.pitch_rad)
        return np.ascontiguousarray(np.stack([c - vv * s, -uu, -s - vv * c], axis=-1))

    def _sky_tables(self) -> None:
        """Panorama row and azimuth of each pixel, seen through the middle of its row's part above the horizon."""
        m = self.model
        rows = np.arange(m.height, dtype=np.float64)
        sky_mid = 0.5 * (rows + np.minimum(rows + 1.0, max(m.horizon_v, 0.0)))
        r = m.rays(dv=(sky_mid - (rows + 0.5))[:, None])
        el = np.arctan2(r[..., 2], np.hypot(r[..., 0], r[..., 1]))
        self.sky_el_bins = int(math.ceil(max(float(el.max()), 0.0) / SKY_EL_STEP_RAD)) + 2
        self.sky_el = np.clip(np.floor(el / SKY_EL_STEP_RAD), 0, self.sky_el_bins - 1).astype(np.int64)
        self.sky_az = np.ascontiguousarray(np.arctan2(r[..., 1], r[..., 0]) * (SKY_AZ_BINS / (2 * math.pi)))

