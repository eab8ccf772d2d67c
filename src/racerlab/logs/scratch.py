"""racerlab's temporary folders, in one place: `<temp>/racerlab-<user>/<kind>-pid<pid>-<random>/`.

`<temp>` is `RACERLAB_TMPDIR`, else the system's (`TMPDIR`, `/tmp`). A folder is removed when its `with` block
ends, however it ends (an error, Ctrl-C); a process killed with -9 cannot clean up, so the next racerlab that
makes a temporary folder removes the folders of processes that are gone. Atomic writes' own temporary files
(`logs.atomic`) live beside their targets and are swept the same way, by the PID in their names.
"""

from __future__ import annotations

import os
import re
import shutil
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

SCRATCH_ENV = "RACERLAB_TMPDIR"


def pid_alive(pid: int) -> bool:
    """Whether a process with this PID exists (it may be another program that reuses the number)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # it exists, under another user
        return True
    except OSError:  # pragma: no cover - Windows: no such process
        return False
    return True


def scratch_root() -> Path:
    """This user's folder of racerlab temporary folders (created private; a planted link or another user's
    folder of that name is never used)."""
    base = Path(os.environ.get(SCRATCH_ENV) or tempfile.gettempdir())
    uid = os.getuid() if hasattr(os, "getuid") else os.getlogin()
    root = base / f"racerlab-{uid}"
    try:
        root.mkdir(mode=0o700, parents=True)
    except FileExistsError:
        st = os.lstat(root)
        mine = not hasattr(os, "getuid") or st.st_uid == os.getuid()
        if not stat.S_ISDIR(st.st_mode) or not mine:
            return Path(tempfile.mkdtemp(prefix="racerlab-", dir=base))
    return root


OWNER_RE = re.compile(r"(?:-pid|\.tmp-|\.part-)(\d+)-[A-Za-z0-9_]+$")


def owner_pid(name: str) -> int | None:
    """The PID written in a temporary name: `<kind>-pid<pid>-<random>` (a scratch folder), `.<name>.tmp-<pid>-<r>`
    (an atomic write), `.<name>.part-<pid>-<r>` (a download)."""
    m = OWNER_RE.search(name)
    return int(m.group(1)) if m else None


def sweep(folder: Path, is_ours=lambda name: True) -> list[Path]:
    """Remove the entries of `folder` (those `is_ours` accepts) whose owner process (`owner_pid`) is gone."""
    removed = []
    try:
        entries = list(folder.iterdir())
    except OSError:
        return removed
    for p in entries:
        pid = owner_pid(p.name)
        if not is_ours(p.name) or pid is None or pid == os.getpid() or pid_alive(pid):
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
        removed.append(p)
    return removed


@contextmanager
def scratch_dir(kind: str) -> Iterator[Path]:
    """A fresh private temporary folder for the `with` block; it is removed when the block ends."""
    root = scratch_root()
    sweep(root)
    path = Path(tempfile.mkdtemp(prefix=f"{kind}-pid{os.getpid()}-", dir=root))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)
