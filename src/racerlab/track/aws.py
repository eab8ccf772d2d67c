"""The AWS DeepRacer tracks by name: download them from the community's public track data, or import a folder.

racerlab ships no AWS route file, only a table of them (`racerlab/data/aws_tracks.csv`: file name, size,
sha256, display name, the repository that holds it). `fetch(names)` downloads files from
`aws-deepracer-community/deepracer-race-data` (`raw_data/tracks/npy/`; the three `reinvent_*` world files,
byte-identical to `reinvent_base`, from `deepracer-simapp`'s `bundle/routes/`), both pinned to the commit the
table was made from, checks every file against its sha256 and saves it in the user track folder, where
`racerlab.track.load(name)` finds it. `RACERLAB_AWS_TRACKS_URL` points the downloads at a mirror: a URL
(or folder) that serves the files under their own names. `import_folder(path)` copies the AWS route files
found anywhere under a folder the user already has (a DRfC or simapp checkout), checked the same way.

The table is made from a folder of the files with `python -m racerlab.track.aws FOLDER` (which reads the
folder's MANIFEST.csv for display names and sources).
"""

from __future__ import annotations

import csv
import hashlib
import os
import sys
import urllib.error
import urllib.request
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from racerlab.errors import TrackError

TABLE = Path(__file__).resolve().parent.parent / "data" / "aws_tracks.csv"
MIRROR_ENV = "RACERLAB_AWS_TRACKS_URL"
RACE_DATA = "aws-deepracer-community/deepracer-race-data"
SIMAPP = "aws-deepracer-community/deepracer-simapp"
SOURCES = {  # repository -> raw URL of its route folder at the commit the sums were taken from
    RACE_DATA: "https://raw.githubusercontent.com/aws-deepracer-community/deepracer-race-data/"
               "a2cdeadf8b011769110bfece186c28f838355977/raw_data/tracks/npy/",
    SIMAPP: "https://raw.githubusercontent.com/aws-deepracer-community/deepracer-simapp/"
            "01f5f015fd852f952b351643898d4beb4f36494b/bundle/routes/",
}
TIMEOUT_S = 30
MAX_BYTES = 1 << 20  # the largest route file is about 30 kB


@dataclass(frozen=True)
class AwsTrack:
    name: str  # the file name without .npy: the name racerlab loads it by
    size: int
    sha256: str
    title: str  # the console's display name
    repo: str

    @property
    def file(self) -> str:
        return f"{self.name}.npy"

    def url(self, mirror: str | None = None) -> str:
        base = mirror if mirror is not None else SOURCES[self.repo]
        if "://" not in base:  # a folder
            return Path(base, self.file).resolve().as_uri()
        return base.rstrip("/") + "/" + self.file


@lru_cache(maxsize=1)
def catalogue() -> dict[str, AwsTrack]:
    """Every AWS route file racerlab knows, by name."""
    with open(TABLE, newline="", encoding="utf-8") as f:
        return {r["name"]: AwsTrack(r["name"], int(r["bytes"]), r["sha256"], r["title"], r["repo"])
                for r in csv.DictReader(f)}


def fetch_hint(name: str) -> str | None:
    """One line saying how to get the AWS track `name` (None for a name that is not an AWS track)."""
    stem = name[:-4] if name.endswith(".npy") else name
    if stem not in catalogue():
        return None
    return (f"{stem} is an AWS track that is not downloaded yet: run `racerlab tracks fetch {stem}` "
            f"(or `racerlab tracks fetch --all`)")


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _check(t: AwsTrack, data: bytes, where: str) -> None:
    got = sha256(data)
    if got != t.sha256:
        raise TrackError(f"{where}: sha256 {got[:16]}... is not the {t.file} racerlab knows ({t.sha256[:16]}...); "
                         f"the download was damaged or the source changed: nothing was saved, try again")


def _save(folder: Path, t: AwsTrack, data: bytes) -> Path:
    from racerlab.logs.atomic import atomic_write_bytes

    return atomic_write_bytes(folder / t.file, data, fsync=False)


def _download(url: str) -> bytes:
    try:
        with urllib.request.urlopen(url, timeout=TIMEOUT_S) as r:  # noqa: S310 - https, or the user's mirror
            return r.read(MAX_BYTES + 1)
    except urllib.error.HTTPError as e:
        raise TrackError(f"{url}: the server answered {e.code} {e.reason}; check the name, or the mirror in "
                         f"${MIRROR_ENV}") from None
    except (urllib.error.URLError, OSError) as e:
        reason = getattr(e, "reason", e)
        raise TrackError(f"{url}: cannot download ({reason}); check the network connection, or set ${MIRROR_ENV} "
                         f"to a mirror, or use `racerlab tracks import DIR` on a folder you have") from None


def resolve_names(names: list[str], everything: bool = False) -> list[AwsTrack]:
    """The table entries for `names` (file names with .npy are fine); a clear error for unknown ones."""
    cat = catalogue()
    if everything:
        return list(cat.values())
    out = []
    for n in names:
        stem = n[:-4] if n.endswith(".npy") else n
        if stem not in cat:
            import difflib

            close = difflib.get_close_matches(stem, list(cat), n=3, cutoff=0.6)
            hint = f"; did you mean {', '.join(close)}?" if close else "; `racerlab tracks fetch --list` shows them"
            raise TrackError(f"{n!r} is not an AWS track racerlab knows{hint}")
        out.append(cat[stem])
    return out


def fetch(tracks: list[AwsTrack], folder: Path, mirror: str | None = None,
          report=None) -> tuple[list[Path], list[Path]]:
    """Download `tracks` into `folder`; returns (downloaded, already there with the right sha256)."""
    mirror = mirror if mirror is not None else os.environ.get(MIRROR_ENV) or None
    done, kept = [], []
    for t in tracks:
        target = folder / t.file
        if target.is_file() and sha256(target.read_bytes()) == t.sha256:
            kept.append(target)
            continue
        url = t.url(mirror)
        data = _download(url)
        _check(t, data, url)
        done.append(_save(folder, t, data))
        if report:
            report(t, done[-1])
    return done, kept


@dataclass
class ImportResult:
    copied: list[Path]
    already: list[Path]
    mismatched: list[Path]  # an AWS file name whose bytes are not the known file
    other: int  # .npy files that are not AWS route files (racing lines, ...)


def import_folder(source: Path, folder: Path) -> ImportResult:
    """Copy every AWS route file found under `source` (any depth) into `folder`, checked by sha256."""
    source = Path(source)
    if not source.is_dir():
        raise TrackError(f"{source}: not a folder; give the folder that holds the .npy route files "
                         f"(a DRfC checkout, simapp's bundle/routes)")
    cat = catalogue()
    res = ImportResult([], [], [], 0)
    for p in sorted(source.rglob("*.npy")):
        t = cat.get(p.stem)
        if t is None:
            res.other += 1
            continue
        data = p.read_bytes()
        if sha256(data) != t.sha256:
            res.mismatched.append(p)
            continue
        target = folder / t.file
        if target.is_file() and sha256(target.read_bytes()) == t.sha256:
            res.already.append(target)
        else:
            res.copied.append(_save(folder, t, data))
    return res


# ---------------------------------------------------------------------------------------------------------
# making the table


def write_table(files_dir: Path, out: Path = TABLE) -> int:
    """The table of every `.npy` in `files_dir` (display names and repositories from its MANIFEST.csv)."""
    manifest = {}
    m = files_dir / "MANIFEST.csv"
    if m.is_file():
        with open(m, newline="", encoding="utf-8") as f:
            manifest = {r["file"]: r for r in csv.DictReader(f)}
    rows = []
    for p in sorted(files_dir.glob("*.npy")):
        info = manifest.get(p.name, {})
        data = p.read_bytes()
        rows.append({"name": p.stem, "bytes": len(data), "sha256": sha256(data), "title": info.get("name", p.stem),
                     "repo": info.get("source_repo") or RACE_DATA})
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=["name", "bytes", "sha256", "title", "repo"], lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    return len(rows)


if __name__ == "__main__":  # pragma: no cover
    print(write_table(Path(sys.argv[1])), "tracks ->", TABLE)
