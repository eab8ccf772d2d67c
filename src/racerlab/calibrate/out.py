"""Where `racerlab calibrate --out` writes, checked before the fit: a new `.toml` file, an earlier `[car]` table or
a model's training.toml, into which the new `[car]` table is merged (every other table and key kept), atomically.

Nothing else is overwritten: not a file that is not TOML (notes, a picture, a device), not a TOML file with tables
a training.toml does not have (pyproject.toml), not a picture beside it that racerlab calibrate did not draw.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from racerlab.calibrate.fit import FITTED
from racerlab.errors import ConfigError
from racerlab.logs.atomic import check_output

PNG_MARK = b"racerlab calibrate"  # the PNG's Software text: a picture this command drew and may redraw
TRAINING_TABLES = ("track", "run", "stop", "evaluation", "logs", "randomise", "race", "car", "teacher", "worker")
_HEADER = re.compile(r"^\s*\[\s*car\s*\]\s*(#.*)?$")
_ANY_HEADER = re.compile(r"^\s*\[")
_OUR_COMMENTS = ("# racerlab calibrate", "# held-out median front-point error")
_PROBE = "[car]\nsimulator = \"droa\"\n" + "".join(f"{name} = 1.0\n" for name in FITTED)


def check_out(out: Path) -> Path:
    """The file `--out` names, resolved (a symlink's target), once it is known that writing there loses nothing;
    one line naming the problem and the fix otherwise. Its picture goes beside it as `.png`."""
    if str(out) in ("", ".") or out.suffix.lower() != ".toml":
        raise ConfigError(f"--out {str(out)!r}: the [car] table goes into a .toml file; give e.g. --out car.toml or "
                          "--out MODEL/training.toml")
    path = check_output(out, "--out", "a new file name or a model's training.toml")
    if path.exists():
        _check_toml(out, path)
        table_text(path, _PROBE)  # a [car] table it cannot merge into is found now, not after the fit
    _check_picture(out, path.with_suffix(".png"))
    return path


def _check_toml(out: Path, path: Path) -> None:
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"--out {out}: the file is there and is not a TOML file ({type(exc).__name__}); racerlab "
                          "merges its [car] table only into a training.toml or an earlier car.toml: give a new "
                          "file name") from None
    other = sorted(set(data) - set(TRAINING_TABLES))
    if other:
        raise ConfigError(f"--out {out}: a TOML file with [{other[0]}], not a training.toml or a [car] table; "
                          "give a new file name or a model's training.toml")


def _check_picture(out: Path, png: Path) -> None:
    if not (png.exists() or png.is_symlink()):
        return
    try:
        ours = png.is_file() and not png.is_symlink() and PNG_MARK in png.read_bytes()[:4096]
    except OSError:
        ours = False
    if not ours:
        raise ConfigError(f"--out {out}: its picture would replace {png}, which racerlab calibrate did not draw; "
                          "move that file or give --out another name")


def merged(existing: str, table: str) -> str:
    """`existing` TOML text with `table` (a `[car]` table with its comment lines) merged in: the keys it sets
    replace theirs in the existing `[car]` table, its comments replace those of an earlier calibration, every
    other line stays; no `[car]` table: the table is appended."""
    lines = existing.splitlines()
    at = next((i for i, line in enumerate(lines) if _HEADER.match(line)), None)
    if at is None:
        return existing.rstrip("\n") + ("\n\n" if existing.strip() else "") + table
    new = table.splitlines()
    keys = {_key(line): line for line in new if _key(line)}
    end = next((i for i in range(at + 1, len(lines)) if _ANY_HEADER.match(lines[i])), len(lines))
    head = lines[:at]
    while head and head[-1].startswith(_OUR_COMMENTS):
        head.pop()
    body = [keys.get(_key(line), line) for line in lines[at + 1:end] if not line.startswith(_OUR_COMMENTS)]
    while body and not body[-1].strip():
        body.pop()
    body += [line for key, line in keys.items() if key not in {_key(b) for b in body}]
    tail = [""] + lines[end:] if end < len(lines) else []
    return "\n".join([*head, *(line for line in new if line.startswith("#")), lines[at], *body, *tail]) + "\n"


def _key(line: str) -> str | None:
    head = line.split("=", 1)[0].strip() if "=" in line and not line.lstrip().startswith("#") else ""
    return head.strip("\"'") or None


def table_text(path: Path, table: str) -> str:
    """What `path` will hold: `table` alone for a new file, else merged into it; checked to read back as TOML whose
    `[car]` is exactly `table`'s."""
    text = merged(path.read_text(encoding="utf-8-sig"), table) if path.exists() else table
    want = tomllib.loads(table)["car"]
    try:
        got = tomllib.loads(text).get("car", {})
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"--out {path}: merging the [car] table into it gives invalid TOML ({exc}); give a new "
                          "file name and copy the table by hand") from None
    if any(got.get(k) != v for k, v in want.items()):
        raise ConfigError(f"--out {path}: its [car] table is written in a way racerlab cannot merge into (a dotted "
                          "or inline table); give a new file name and copy the table by hand")
    return text
