"""Reading what people send: race options from a form or JSON, uploads saved to the league's uploads folder.

Numbers and yes/no fields go through the console's readers (`console.security.number`, `flag`: one line naming
the field). A race's track from the web is a name the server knows (`racerlab.track.registry.names()`) or an
uploaded track file; never a path on the server. Uploads keep only a cleaned base name with an archive suffix,
in a fresh folder under DIR/uploads that is removed once the submission has been converted.
"""

from __future__ import annotations

import re
import secrets
import shutil
from contextlib import asynccontextmanager
from pathlib import Path

from racerlab.console.security import flag, number, save_upload
from racerlab.league.races import RaceOptions
from racerlab.league.store import LeagueError

ARCHIVE_SUFFIXES = (".tar.gz", ".tgz", ".tar", ".zip")
TRACK_SUFFIXES = (".npy", ".csv")
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")
INTS = {"laps": (1, 20), "min_laps": (1, 20), "max_resets": (0, 10_000), "obstacles": (0, 6), "bots": (0, 6),
        "seed": (0, 2**31 - 1), "max_submissions": (1, 10_000)}
FLOATS = {"off_track_penalty": (0, 60), "collision_penalty": (0, 60), "time_cap_s": (10, 1800), "bot_speed": (0.1, 7)}
FLAGS = {"reverse": False, "lane_change": False, "video": True, "public_videos": True}
TEXTS = ("race_type", "timing", "car", "description", "opens", "closes")


def known_tracks() -> list[str]:
    from racerlab.track import registry

    return registry.names()


def check_track(name: str, what: str = "track") -> str:
    """A track name the server knows (never a path: the web does not read files of the server's choosing)."""
    name = str(name or "").strip()
    if name not in known_tracks():
        raise LeagueError(f"{what} {name!r}: not a track this server knows; pick one from the list or upload the "
                          "track file (.npy)")
    return name


def race_options(fields: dict, tz_minutes: str | None = None) -> dict:
    """`League.create_race`'s options from a form's fields (strings; checkboxes present or absent)."""
    opts: dict = {}
    for key, (low, high) in INTS.items():
        value = number(fields, key, integer=True, low=low, high=high)
        if value is not None:
            opts[key] = value
    for key, (low, high) in FLOATS.items():
        value = number(fields, key, low=low, high=high)
        if value is not None:
            opts[key] = value
    for key, default in FLAGS.items():
        opts[key] = flag(fields, key, False) if fields.get("_checkboxes") else flag(fields, key, default)
    for key in TEXTS:
        text = str(fields.get(key) or "").strip()
        if text:
            opts[key] = text
    for key in ("opens", "closes"):
        if key in opts:
            opts[key] = with_zone(opts[key], tz_minutes)
    return opts


def with_zone(text: str, tz_minutes: str | None) -> str:
    """A browser's local time (`2026-05-01T18:00`, no zone) with the browser's offset from UTC (`tz_minutes`,
    JavaScript's getTimezoneOffset: minutes *behind* UTC) added; other texts (`+2h`, `now`, ISO with a zone) as
    they are."""
    if not re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d(:\d\d)?", text) or tz_minutes in (None, ""):
        return text
    try:
        behind = int(tz_minutes)
    except ValueError:
        return text
    ahead = -behind
    sign = "+" if ahead >= 0 else "-"
    return f"{text}{sign}{abs(ahead) // 60:02d}:{abs(ahead) % 60:02d}"


def json_race_options(body: dict) -> dict:
    """The options of `POST /api/races` (a JSON object of `RaceOptions` keys): tracks by name only."""
    opts = {k: v for k, v in body.items() if k != "name"}
    RaceOptions.from_mapping(opts)  # unknown keys and a missing track: one line, before anything is read
    opts["track"] = check_track(opts["track"])
    if opts.get("eval_track"):
        opts["eval_track"] = check_track(opts["eval_track"], "evaluation track")
    return opts


def clean_filename(filename: str | None, suffixes: tuple[str, ...], what: str) -> str:
    """The upload's base name, cleaned, with one of `suffixes`; a one-line refusal for any other file."""
    base = Path(str(filename or "").replace("\\", "/")).name
    lower = base.lower()
    suffix = next((s for s in suffixes if lower.endswith(s)), None)
    if suffix is None:
        raise LeagueError(f"{base or 'the upload'}: upload {what} ({', '.join(suffixes)})")
    stem = _UNSAFE.sub("_", base[: -len(suffix)]).strip("._")[:60] or "upload"
    return stem + suffix


@asynccontextmanager
async def saved(upload, uploads: Path, limit: int, suffixes: tuple[str, ...], what: str):
    """An uploaded file saved under a fresh folder in `uploads` (removed afterwards): yields its path."""
    if upload is None or not getattr(upload, "filename", None):
        raise LeagueError(f"choose {what} to upload")
    name = clean_filename(upload.filename, suffixes, what)
    folder = uploads / f"web-{secrets.token_hex(8)}"
    folder.mkdir(parents=True)
    try:
        path = folder / name
        await save_upload(upload, path, limit)
        if path.stat().st_size == 0:
            raise LeagueError(f"{name}: the file is empty")
        yield path
    finally:
        shutil.rmtree(folder, ignore_errors=True)
