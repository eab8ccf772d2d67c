"""Lap videos: the evaluation seen from above, one frame per simulator step (15 fps = real time).

The track is drawn once with matplotlib (`racerlab.track.plot.draw_track`) into an RGB picture;
each frame copies it, adds the newest piece of the car's trail (coloured by ground speed; the
trail picture persists, so nothing is redrawn) and then draws the car to scale (0.196 m × 0.324 m,
AWS's collision box), with the race's boxes or bot cars where they were at that step (boxes in cardboard,
bot cars and the other racer of a head-to-model race in blue). Beside the track, never over it, a panel
holds what the camera saw (camera models), the lap timer, speed, progress, every finished lap's time and
the trail's colour scale; it is as tall as the laps it lists need. During a penalty the car blinks, as in
the AWS simulator. Frames go to an MP4 through imageio's ffmpeg writer.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from racerlab.errors import RacerlabError
from racerlab.spec import STEPS_PER_SECOND
from racerlab.track.core import Track

FPS = STEPS_PER_SECOND  # one frame per simulator step: real time
CAR_LENGTH_M = 0.324  # BOT_CAR_DIMENSION (facts §2), centred on the base pose
CAR_WIDTH_M = 0.196
SPEED_CMAP = "plasma"
MAX_TRAIL_JUMP_M = 0.5  # longer moves between rows are resets: no trail line
BOX_FILL, BOX_EDGE = (200, 160, 110, 255), (90, 60, 20, 255)  # TrackLook.box
BOT_FILL, BOT_EDGE = (90, 100, 190, 255), (20, 25, 70, 255)  # TrackLook.bot_car
TEXT = (20, 20, 20)
# H.264 settings: crf 15 (imageio's quality 7) and x264's fastest preset, which encodes the mostly still top-down
# picture at about a third of the default preset's CPU time (medium 11.6 CPU-s, ultrafast 4.3 for a 477-frame
# 1296x752 video) for a file about three times larger (3.7 MB against 1.3 MB)
QUALITY = 7
PRESET = "ultrafast"


def camera_image(obs) -> np.ndarray | None:
    """The first car's camera picture in an observation, as a greyscale uint8 image (stereo side by side);
    None when the observation has no image (features, lidar)."""
    arrays = obs.values() if isinstance(obs, dict) else [obs]
    for a in arrays:
        a = np.asarray(a)
        if a.ndim < 3:
            continue
        img = a[0]
        if img.ndim == 3:
            if not (img.shape[0] <= 4 and img.shape[0] < img.shape[-1]):
                img = np.moveaxis(img, -1, 0)  # channels last -> first
            img = np.concatenate(list(img), axis=1)
        if img.dtype != np.uint8:
            img = np.asarray(img, dtype=np.float64)
            img = img * 255.0 if img.max(initial=0.0) <= 1.0 else img
            img = np.clip(img, 0, 255).astype(np.uint8)
        return img
    return None


class TrackCanvas:
    """The static top-down picture of a track and the metres → pixels mapping."""

    def __init__(self, track: Track, width_px: int = 960, margin_m: float = 0.3):
        pts = np.vstack([track.inner, track.outer])
        lo = pts.min(axis=0) - margin_m
        hi = pts.max(axis=0) + margin_m
        span = hi - lo
        self.width = _even16(width_px)
        self.scale = self.width / span[0]
        self.height = _even16(span[1] * self.scale)
        # stretch the y range so that pixels stay square after rounding the height
        self.x0, self.x1 = lo[0], hi[0]
        mid_y = 0.5 * (lo[1] + hi[1])
        half_h = 0.5 * self.height / self.scale
        self.y0, self.y1 = mid_y - half_h, mid_y + half_h
        self.background = self._render(track)

    def _render(self, track: Track) -> np.ndarray:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        from racerlab.track.plot import draw_track

        dpi = 100
        fig = Figure(figsize=(self.width / dpi, self.height / dpi), dpi=dpi)
        ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
        draw_track(track, ax, waypoint_numbers=False, title=False, legend=False)
        ax.set_aspect("auto")
        ax.set_xlim(self.x0, self.x1)
        ax.set_ylim(self.y0, self.y1)
        ax.set_axis_off()
        agg = FigureCanvasAgg(fig)
        agg.draw()
        return np.asarray(agg.buffer_rgba())[..., :3].copy()

    def px(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (column, row) of points in metres."""
        return (np.asarray(x) - self.x0) * self.scale, (self.y1 - np.asarray(y)) * self.scale


def _even16(x: float) -> int:
    """Round a frame size to a multiple of 16 (what H.264 encoders want)."""
    return max(16, int(round(x / 16.0)) * 16)


def _speed_colours(speed: np.ndarray, vmax: float) -> list[tuple[int, int, int]]:
    from matplotlib import colormaps

    cmap = colormaps[SPEED_CMAP]
    rgb = cmap(np.clip(speed / max(vmax, 1e-6), 0.0, 1.0))[:, :3]
    return [tuple(int(round(c * 255)) for c in row) for row in rgb]


def car_polygon(canvas: TrackCanvas, x: float, y: float, yaw: float, size=(CAR_LENGTH_M, CAR_WIDTH_M)
                ) -> list[tuple[float, float]]:
    """The corners in pixels (front first) of the car's footprint, or of a rectangle of `size` (length, width)."""
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = 0.5 * size[0], 0.5 * size[1]
    corners = [(hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw)]
    xs = [x + a * c - b * s for a, b in corners]
    ys = [y + a * s + b * c for a, b in corners]
    px, py = canvas.px(xs, ys)
    return list(zip(px.tolist(), py.tolist(), strict=True))


class Glyphs:
    """The characters of a font, each rendered once, and the last lines drawn with them. (Pillow lays out and
    rasterises a whole line in about 4 ms; a video's panel drew five lines a frame, more than the rest of the frame
    and its encoding together. Most lines repeat from frame to frame: the title, the finished laps.) The font's
    advances carry no kerning, so a line composed of glyphs is placed as Pillow would place it."""

    MAX_LINES = 256

    def __init__(self, font):
        self.font = font
        self.cache: dict[str, tuple] = {}
        self.lines: dict[str, tuple] = {}

    def _glyph(self, ch: str) -> tuple:
        """(ink as a uint8 array or None, left, top, advance) of one character."""
        g = self.cache.get(ch)
        if g is None:
            from PIL import Image, ImageDraw

            left, top, right, bottom = self.font.getbbox(ch)
            ink = None
            if right > left and bottom > top:
                mask = Image.new("L", (right - left, bottom - top), 0)
                ImageDraw.Draw(mask).text((-left, -top), ch, fill=255, font=self.font)
                ink = np.asarray(mask)
            g = self.cache[ch] = (ink, left, top, self.font.getlength(ch))
        return g

    def _line(self, text: str) -> tuple:
        """(mask, left, top) of a whole line, composed from glyphs and kept for the frames that show it again."""
        hit = self.lines.get(text)
        if hit is None:
            placed, x = [], 0.0
            for ch in text:
                ink, left, top, advance = self._glyph(ch)
                if ink is not None:
                    placed.append((ink, int(round(x)) + left, top))
                x += advance
            hit = self._compose(placed)
            if len(self.lines) >= self.MAX_LINES:
                self.lines.pop(next(iter(self.lines)))
            self.lines[text] = hit
        return hit

    @staticmethod
    def _compose(placed: list) -> tuple:
        from PIL import Image

        if not placed:
            return None, 0, 0
        x0, y0 = min(p[1] for p in placed), min(p[2] for p in placed)
        x1 = max(p[1] + p[0].shape[1] for p in placed)
        y1 = max(p[2] + p[0].shape[0] for p in placed)
        line = np.zeros((y1 - y0, x1 - x0), dtype=np.uint8)
        for ink, gx, gy in placed:  # glyphs may overlap by a pixel: keep the stronger ink of both
            h, w = ink.shape
            view = line[gy - y0:gy - y0 + h, gx - x0:gx - x0 + w]
            np.maximum(view, ink, out=view)
        return Image.fromarray(line, "L"), x0, y0

    def text(self, draw, xy: tuple[int, int], text: str, fill) -> None:
        mask, left, top = self._line(text)
        if mask is not None:
            draw.bitmap((int(xy[0]) + left, int(xy[1]) + top), mask, fill=fill)


class _Hud:
    """Text and pictures drawn over each frame."""

    LINE = 21  # text line height at scale 1 (px)

    def __init__(self, title: str, laps_wanted: int, vmax: float, scale: int):
        from PIL import ImageFont

        self.font = ImageFont.load_default(size=16 * scale)
        self.small = ImageFont.load_default(size=12 * scale)
        self.glyphs = Glyphs(self.font)
        self.title = title
        self.laps_wanted = laps_wanted
        self.vmax = vmax
        self.scale = scale

    def max_lines(self) -> int:
        """Title, lap clock, speed and progress, state, then one line per lap."""
        return (1 if self.title else 0) + 3 + self.laps_wanted

    def text_height(self) -> int:
        return (12 + self.LINE * self.max_lines()) * self.scale

    def draw(self, draw, lines: list[str], x0: int, y0: int) -> None:
        s = self.scale
        for i, t in enumerate(lines):
            self.glyphs.text(draw, (x0 + 10 * s, y0 + 6 * s + self.LINE * s * i), t, TEXT)

    def speed_bar(self, draw, x0: int, width: int, height: int, colours: list) -> None:
        """The trail's colour scale (drawn once, into the frame's blank panel)."""
        s = self.scale
        w, h = width - 20 * s, 10 * s
        x0, y0 = x0 + 10 * s, height - 20 * s
        for i in range(w):
            draw.line((x0 + i, y0, x0 + i, y0 + h), fill=colours[int(i / w * (len(colours) - 1))])
        draw.text((x0, y0 - 19 * s), f"trail: speed 0 to {self.vmax:.1f} m/s", fill=TEXT, font=self.small)


def render_video(path, track: Track, run, *, title: str = "", max_speed: float = 4.0, width_px: int = 960,
                 progress: Callable[[int, int], None] | bool = False, frame_every: int = 1) -> Path:
    """Write the evaluation `run` (an `EvalRun`) on `track` (driving direction) as an MP4 at `path`. With
    `frame_every` k > 1 every k-th step is a frame (the last step always), at FPS / k: still real time, k times
    cheaper to draw and encode; the trail and the lap times keep every step."""
    from PIL import Image, ImageDraw

    path = Path(path)
    canvas = TrackCanvas(track, width_px)
    scale = max(1, int(round(canvas.width / 960)))
    extra, trace = run.extra, run.trace
    n = run.rows
    colours = _speed_colours(extra["speed"], max_speed)
    hud = _Hud(title, int(trace["episode"].max(initial=0)) + 1, max_speed, scale)
    bar = _speed_colours(np.linspace(0, max_speed, 64), max_speed)
    report = _progress_printer(progress)
    inset = _inset_size(run.frames, scale)
    side = _Side(canvas, hud, inset, scale)
    hud.speed_bar(ImageDraw.Draw(side.blank), side.x0, side.width, side.height, bar)
    trail = Image.fromarray(canvas.background)
    tdraw = ImageDraw.Draw(trail)
    px, py = canvas.px(extra["base_x"], extra["base_y"])
    lap_of = trace["episode"]
    lap_end = lap_ends(trace)
    lap_times: list[str] = []
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")  # published by rename when complete
    writer = _open_writer(tmp, side.blank.size, FPS / frame_every)
    try:
        for i in range(n):
            if i and lap_of[i] != lap_of[i - 1] and trace["episode_status"][i] == "prepare":
                trail = Image.fromarray(canvas.background)  # a new trial from the line: a clean track
                tdraw = ImageDraw.Draw(trail)
            if i and trace["episode_status"][i] != "pause" and math.hypot(
                    extra["base_x"][i] - extra["base_x"][i - 1], extra["base_y"][i] - extra["base_y"][i - 1]) \
                    < MAX_TRAIL_JUMP_M:
                tdraw.line((px[i - 1], py[i - 1], px[i], py[i]), fill=colours[i], width=3 * scale)
            if lap_end[i]:
                lap_times.append(f"lap {len(lap_times) + 1}: {extra['lap_clock'][i]:.3f} s")
            if (n - 1 - i) % frame_every:
                continue
            frame = side.frame(trail)
            shapes = ImageDraw.Draw(frame, "RGBA")
            if run.objects is not None:
                draw_objects(shapes, canvas, run.objects["pose"][i], run.objects["size"], run.objects["cars"])
            _draw_car(shapes, canvas, extra, trace, i)
            draw = ImageDraw.Draw(frame)
            hud.draw(draw, _hud_lines(hud, trace, extra, i, lap_times, bool(lap_end[i])), side.x0, side.text_y)
            if inset and run.frames[i] is not None:
                _inset(frame, run.frames[i], side.x0, scale)
            writer.send(frame.tobytes())
            report(i + 1, n)
        writer.close()
        os.replace(tmp, path)
    finally:
        writer.close()
        tmp.unlink(missing_ok=True)
    return path


def lap_ends(trace) -> np.ndarray:
    """Per row: a lap ended here. Laps end at progress 100; in a continuous evaluation only the trial's last
    lap says `lap_complete`, the others stay `in_progress` as in AWS's logs."""
    status = np.asarray(trace["episode_status"]).astype(str)
    return (status == "lap_complete") | ((np.asarray(trace["progress"]) >= 100.0) & (status != "pause"))


class _Side:
    """The frame: the track picture on the left, the panel (camera, text, colour scale) to its right."""

    def __init__(self, canvas: TrackCanvas, hud: _Hud, inset: tuple[int, int] | None, scale: int):
        from PIL import Image

        self.x0 = canvas.width
        self.width = _even16(max(300 * scale, (inset[0] if inset else 0) + 20 * scale))
        self.text_y = (inset[1] + 20 * scale) if inset else 0
        self.height = max(canvas.height, _even16(self.text_y + hud.text_height() + 50 * scale + 8))
        self.blank = Image.new("RGB", (canvas.width + self.width, self.height), (255, 255, 255))

    def frame(self, trail):
        frame = self.blank.copy()
        frame.paste(trail, (0, 0))
        return frame


def _inset_size(frames, scale: int) -> tuple[int, int] | None:
    """Width and height of the camera picture as drawn, or None without pictures."""
    first = next((f for f in frames or [] if f is not None), None)
    if first is None:
        return None
    factor = 2 * scale if first.shape[1] <= 200 else scale
    return first.shape[1] * factor, first.shape[0] * factor


def _hud_lines(hud: _Hud, trace, extra, i: int, lap_times: list[str], lap_end: bool) -> list[str]:
    lap = min(int(trace["episode"][i]) + 1, hud.laps_wanted)
    status = "lap_complete" if lap_end else str(trace["episode_status"][i])
    state = {"pause": f"penalty: {trace['pause_duration'][i]:.1f} s left", "off_track": "off track!",
             "reversed": "reversed!", "immobilized": "immobilized!", "crashed": "crashed!",
             "lap_complete": "lap complete", "prepare": "ready"}.get(status, "")
    lines = [hud.title] if hud.title else []
    lines += [f"lap {lap}/{hud.laps_wanted}   {extra['lap_clock'][i]:6.2f} s",
              f"speed {extra['speed'][i]:.2f} m/s   progress {trace['progress'][i]:5.1f} %"]
    lines.append(state)
    return lines + lap_times


def _draw_car(draw, canvas: TrackCanvas, extra, trace, i: int) -> None:
    x, y, yaw = extra["base_x"][i], extra["base_y"][i], extra["base_yaw"][i]
    poly = car_polygon(canvas, x, y, yaw)
    paused = trace["episode_status"][i] == "pause"
    if paused and (i // 3) % 2:  # blink while held, as AWS's BlinkEffect
        fill, edge = (30, 120, 255, 70), (30, 120, 255, 120)
    else:
        fill, edge = (30, 120, 255, 255), (0, 0, 0, 255)
    draw.polygon(poly, fill=fill, outline=edge)
    (fx1, fy1), (fx2, fy2) = poly[0], poly[1]
    draw.line((fx1, fy1, fx2, fy2), fill=(255, 255, 255, 255), width=2)  # the front


def draw_objects(draw, canvas: TrackCanvas, poses, size, cars: bool) -> None:
    """The race's objects (rows x, y, yaw) to scale: boxes, or bot cars with a white front edge."""
    fill, edge = (BOT_FILL, BOT_EDGE) if cars else (BOX_FILL, BOX_EDGE)
    for x, y, yaw in np.asarray(poses, dtype=np.float64).tolist():
        poly = car_polygon(canvas, x, y, yaw, size)
        draw.polygon(poly, fill=fill, outline=edge)
        if cars:
            (fx1, fy1), (fx2, fy2) = poly[0], poly[1]
            draw.line((fx1, fy1, fx2, fy2), fill=(255, 255, 255, 255), width=2)


def _inset(frame, image: np.ndarray, x0: int, scale: int) -> None:
    """What the camera saw, at the top of the panel, at twice its size."""
    from PIL import Image

    pic = Image.fromarray(image).convert("RGB")
    factor = 2 * scale if image.shape[1] <= 200 else scale
    pic = pic.resize((image.shape[1] * factor, image.shape[0] * factor), Image.NEAREST)
    x = x0 + 10 * scale
    frame.paste((20, 20, 20), (x - 3, 7, x + pic.width + 3, 13 + pic.height))
    frame.paste(pic, (x, 10))


class _Writer:
    """Frames (RGB bytes) piped to ffmpeg's H.264 encoder; `close` ends the file (and may be called twice)."""

    def __init__(self, path: Path, size: tuple[int, int], fps: float = FPS):
        try:
            import imageio_ffmpeg
        except ImportError:
            raise RacerlabError("writing a video needs imageio-ffmpeg: pip install imageio-ffmpeg") from None
        path.parent.mkdir(parents=True, exist_ok=True)
        self.gen = imageio_ffmpeg.write_frames(str(path), size, fps=fps, codec="libx264", quality=QUALITY,
                                               macro_block_size=16, ffmpeg_log_level="error",
                                               output_params=["-preset", PRESET])
        self.gen.send(None)
        self.open = True

    def send(self, frame: bytes) -> None:
        self.gen.send(frame)

    def close(self) -> None:
        if self.open:
            self.open = False
            self.gen.close()


def _open_writer(path: Path, size: tuple[int, int], fps: float = FPS) -> _Writer:
    return _Writer(path, size, fps)


def _progress_printer(progress) -> Callable[[int, int], None]:
    if callable(progress):
        return progress
    if not progress:
        return lambda done, total: None
    state = {"shown": -1}

    def show(done: int, total: int) -> None:
        pct = int(100 * done / max(total, 1))
        if pct != state["shown"] and (pct % 5 == 0 or done == total):
            state["shown"] = pct
            end = "\n" if done == total else ""
            print(f"\rrendering video: {done}/{total} frames ({pct} %)", end=end, file=sys.stderr, flush=True)

    return show
