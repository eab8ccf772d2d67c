"""Finding the step logs in a folder, a console `.tar.gz` or a single file, whatever tool wrote them.

Every layout known to the community tools reduces to rules on the relative path of each file:

| path (relative)                                               | what                                     |
|---------------------------------------------------------------|------------------------------------------|
| `[.../][<k>/]training-simtrace/<n>-iteration.csv[.gz]`         | training CSV, iteration n, worker k (0)  |
| `.../evaluation-<stamp>/evaluation-simtrace/<n>-iteration.csv` | evaluation CSV, stream = stamp           |
| `<n>-iteration.csv` directly in the folder loaded              | training CSV (a folder of downloads)     |
| `*.log`, `*.log.<k>` (rolled parts), or the file given         | `SIM_TRACE_LOG:` lines (robomaker/DROA)  |

This covers racerlab model folders, DRfC single- and multi-worker (`<model>/<k>/training-simtrace`),
DRfC uploads and evaluation-only folders, the old console export (`sim-trace/training/training-simtrace`,
`sim-trace/evaluation/<stamp>-<id>/evaluation-simtrace`, `logs/training/*-robomaker.log`) and the new
console / DeepRacer-on-AWS export (`sim-trace/training/<name>/training-simtrace`, `logs/*-simulation.log`).
Paths with a `leaderboard` part are leaderboard runs; `evaluation` (or `eval`) parts mark evaluations.
"""

from __future__ import annotations

import os
import re
import stat
import tarfile
import threading
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from racerlab.logs import files
from racerlab.logs.files import LogFileError, SkippedFiles, check_path, kind_of, read_bytes

TRAINING, EVALUATION, LEADERBOARD = "training", "evaluation", "leaderboard"
CSV, LOG = "csv", "log"

_ITERATION = re.compile(r"^(\d+)-iteration\.csv(?:\.gz)?$")
_ROLLED = re.compile(r"^(?P<base>.+\.log)(?:\.(?P<part>\d+))?$")
_STAMP = re.compile(r"^(?:evaluation-|leaderboard-)?(\d{14})")
SKIP_DIRS = {".racerlab-cache", "__pycache__", ".git", "checkpoints", "model", "ip"}


@dataclass
class Source:
    """One logical log: a simtrace CSV, or a robomaker log with its rolled parts (oldest first)."""

    kind: str  # training | evaluation | leaderboard
    fmt: str  # csv | log
    parts: list[str]  # relative posix paths, read and concatenated in this order
    iteration: int = 0
    worker: int = 0
    stream: str = ""
    workers: int = 1  # training logs found beside this one (DRfC splits each iteration's episodes among them)
    stats: list[tuple[int, int]] = field(default_factory=list)  # (size, mtime_ns) per part

    @property
    def name(self) -> str:
        return self.parts[-1]


class Store:
    """Read access to the files of a folder or an archive, by relative posix path."""

    root: Path
    label: str

    def files(self) -> dict[str, tuple[int, int]]:
        """{relative path: (size, mtime_ns)} of every regular file."""
        raise NotImplementedError

    def read(self, rel: str) -> bytes:
        raise NotImplementedError

    def describe(self, rel: str) -> str:
        """A name for messages: the real path, or `archive.tar.gz:member`."""
        return str(self.root / rel)


class DirStore(Store):
    def __init__(self, root: str | os.PathLike, single: str | None = None):
        self.root = Path(root)
        self.single = single  # one file only (the path given was a file)
        self.label = str(self.root / single) if single else str(self.root)
        self.skipped = SkippedFiles(self.root)

    def files(self) -> dict[str, tuple[int, int]]:
        """Regular files only (links followed): pipes, devices, sockets and broken links are left out and kept in
        `skipped` (`logs.files.SkippedFiles`), for the reader to name."""
        if self.single:
            st = check_path(self.root / self.single)
            return {self.single: (st.st_size, st.st_mtime_ns)}
        out = {}
        skipped = self.skipped = SkippedFiles(self.root)
        for dirpath, dirnames, filenames in os.walk(self.root):
            dirnames[:] = sorted(d for d in dirnames if d not in SKIP_DIRS and not d.startswith("."))
            rel_dir = os.path.relpath(dirpath, self.root)
            for name in filenames:
                if name.startswith("."):
                    continue
                rel = name if rel_dir == "." else PurePosixPath(Path(rel_dir).as_posix(), name).as_posix()
                st = _regular_stat(os.path.join(dirpath, name))
                if isinstance(st, str):
                    skipped.add(rel, st)
                else:
                    out[rel] = (st.st_size, st.st_mtime_ns)
        return out

    def read(self, rel: str) -> bytes:
        return read_bytes(self.root / rel, self.describe(rel))


def _regular_stat(path: str) -> os.stat_result | str:
    """The stat of a regular file (links followed), or what the entry is instead."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "a broken link"
    except OSError as exc:
        return f"not readable ({exc.strerror})"
    return kind_of(st.st_mode) or st


class TarStore(Store):
    """A `.tar`/`.tar.gz` read in place (members are read on demand; the archive is opened once)."""

    def __init__(self, path: str | os.PathLike):
        self.root = Path(path)
        self.label = str(self.root)
        self._tar = tarfile.open(self.root, "r:*")
        self._members = {self._clean(m.name): m for m in self._tar.getmembers() if m.isfile()}
        self._lock = threading.Lock()

    @staticmethod
    def _clean(name: str) -> str:
        return PurePosixPath(name.lstrip("./") if name.startswith("./") else name).as_posix()

    def files(self) -> dict[str, tuple[int, int]]:
        return {n: (m.size, int(m.mtime * 1e9)) for n, m in self._members.items()
                if not any(p.startswith(".") for p in PurePosixPath(n).parts)}

    def read(self, rel: str) -> bytes:
        with self._lock:
            return self._read_member(self._members[rel])

    def read_many(self, rels: list[str]) -> dict[str, bytes]:
        """Members in archive order: one pass over a compressed tar instead of a seek per member."""
        wanted = set(rels)
        out = {}
        with self._lock:
            for m in sorted((self._members[r] for r in wanted), key=lambda m: m.offset):
                out[self._clean(m.name)] = self._read_member(m)
        return out

    def _read_member(self, m: tarfile.TarInfo) -> bytes:
        """A member's bytes, no more than `logs.files.MAX_LOG_BYTES` (its header may claim any size)."""
        if m.size > files.MAX_LOG_BYTES:
            raise LogFileError(f"{self.describe(self._clean(m.name))}: {m.size / 2**30:.1f} GiB, more than racerlab "
                               f"reads from one log file ({files.MAX_LOG_BYTES / 2**30:g} GiB); extract the archive "
                               "and give the folder of the training's per-iteration files")
        f = self._tar.extractfile(m)
        return f.read() if f is not None else b""

    def describe(self, rel: str) -> str:
        return f"{self.root}:{rel}"

    def close(self) -> None:
        self._tar.close()


def open_store(path: str | os.PathLike) -> Store:
    """A store for a folder, a `.tar(.gz)` archive, or a single log/CSV file."""
    path = Path(path)
    if stat.S_ISDIR(check_path(path).st_mode):
        return DirStore(path)
    if tarfile.is_tarfile(path):
        return TarStore(path)
    return DirStore(path.parent, single=path.name)


def classify(files: dict[str, tuple[int, int]], single: bool = False) -> list[Source]:
    """The sources among `files` (relative posix paths -> (size, mtime_ns))."""
    sources: list[Source] = []
    logs: dict[str, dict[int, str]] = {}
    for rel in sorted(files):
        p = PurePosixPath(rel)
        csv = _classify_csv(p)
        if csv is not None:
            sources.append(csv)
            continue
        if single and re.search(r"\.csv(\.gz)?$", p.name):
            sources.append(Source(_kind_of(p), CSV, [rel], stream=_stream_of(p.parent, _kind_of(p))))
            continue
        m = _ROLLED.match(p.name)
        if m or single:
            base = str(p.with_name(m.group("base"))) if m else rel
            part = int(m.group("part") or 0) if m else 0
            logs.setdefault(base, {})[part] = rel
    for base, parts in sorted(logs.items()):
        # rolled parts: the highest number is the oldest (RotatingFileHandler), the bare name the newest
        ordered = [parts[k] for k in sorted(parts, reverse=True) if k] + ([parts[0]] if 0 in parts else [])
        kind = _kind_of(PurePosixPath(base))
        stem = re.sub(r"(-robomaker|-simulation)?\.log$", "", PurePosixPath(base).name)
        sources.append(Source(kind, LOG, ordered, stream=_stream_of(PurePosixPath(stem), kind)))
    for s in sources:
        s.stats = [files[p] for p in s.parts]
    _number_log_workers(sources)
    return sources


def _classify_csv(p: PurePosixPath) -> Source | None:
    m = _ITERATION.match(p.name)
    if not m:
        return None
    iteration = int(m.group(1))
    parent = p.parent
    if parent.name == "evaluation-simtrace" or (parent.name != "training-simtrace" and _kind_of(parent) != TRAINING):
        owner = parent.parent if parent.name == "evaluation-simtrace" else parent
        kind = LEADERBOARD if _kind_of(p) == LEADERBOARD else EVALUATION
        return Source(kind, CSV, [str(p)], iteration=iteration, stream=_stream_of(owner, kind))
    owner = parent.parent if parent.name == "training-simtrace" else parent
    worker = int(owner.name) if owner.name.isdigit() and len(owner.name) <= 3 else 0
    return Source(TRAINING, CSV, [str(p)], iteration=iteration, worker=worker)


def _kind_of(p: PurePosixPath) -> str:
    words = [part.lower() for part in p.parts]
    if any("leaderboard" in w for w in words):
        return LEADERBOARD
    if any("evaluation" in w or re.search(r"(^|[-_.])eval([-_.]|$)", w) for w in words):
        return EVALUATION
    return TRAINING


def _stream_of(owner: PurePosixPath, kind: str) -> str:
    if kind == TRAINING:
        return ""
    m = _STAMP.match(owner.name)
    return m.group(1) if m else (owner.name or "0")


def _number_log_workers(sources: list[Source]) -> None:
    """Several training logs in one folder are several workers (DRfC with multiple robomakers)."""
    logs = [s for s in sources if s.fmt == LOG and s.kind == TRAINING]
    for k, s in enumerate(sorted(logs, key=lambda s: s.name)):
        s.worker = k
        s.workers = len(logs)
