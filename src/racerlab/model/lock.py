"""The training lock: one trainer per model folder, honoured by `racerlab train`, the console and the cluster.

`training.lock` is held with the operating system's own file lock (`flock` on POSIX, `msvcrt.locking` on
Windows) on an open descriptor, for as long as the trainer runs. Taking it is one atomic call, so two
trainers started at the same instant never both win; the kernel drops it when its process ends, however it
ends (kill -9, a crash, a restarted container), so a dead trainer never blocks the folder and a live process
that merely reuses a recorded PID is never mistaken for the holder.

The file also records the holder's PID and its start time, for the message a second trainer gets. On a file
system without file locks (some network mounts) the lock falls back to creating the file exclusively and
recovers a stale one by PID *and* start time: a PID that is alive but started at another time is another
process, and a PID equal to our own is our own stale lock from before a restart.
"""

from __future__ import annotations

import errno
import os
import time
from pathlib import Path

from racerlab.errors import RacerlabError
from racerlab.logs import pid_alive

try:  # POSIX
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None
try:  # Windows
    import msvcrt
except ImportError:
    msvcrt = None

BUSY_TRIES = 5  # a held lock is looked at this many times, BUSY_WAIT_S apart, before the trainer is refused
BUSY_WAIT_S = 0.02
FRESH_S = 2.0  # an empty lock file younger than this is being written, not stale
_UNSUPPORTED = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL}


def process_start(pid: int) -> str | None:
    """When `pid` started, as an opaque string (Linux: clock ticks since boot from /proc), or None when unknown."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[-1].split()
    return fields[19] if len(fields) > 19 else None  # field 22 of stat; fields[0] is field 3


def _same_process(pid: int, start: str | None) -> bool:
    """True while the process `pid` that started at `start` still runs (a reused PID does not count)."""
    if pid == os.getpid():
        return start is not None and start == process_start(pid)
    if not pid_alive(pid):
        return False
    now = process_start(pid)
    return start is None or now is None or now == start


def _try_os_lock(fd: int) -> bool | None:
    """True: locked; False: another open file holds it; None: this file system has no file locks."""
    try:
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        elif msvcrt is not None:  # pragma: no cover - Windows
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        else:  # pragma: no cover
            return None
    except (BlockingIOError, PermissionError):
        return False
    except OSError as exc:
        if exc.errno in (errno.EAGAIN, errno.EACCES):
            return False
        if exc.errno in _UNSUPPORTED:
            return None
        raise
    return True


class TrainingLock:
    """`with TrainingLock(path): ...` — refused (one line with the holder's PID) while another process holds it."""

    def __init__(self, path):
        self.path = Path(path)
        self.held = False
        self._fd: int | None = None
        self._exclusive = False  # held by the O_EXCL fallback rather than an OS lock

    # ---- who holds it ----------------------------------------------------------------------------
    def _recorded(self) -> tuple[int | None, str | None]:
        try:
            return _parse(self.path.read_bytes())
        except OSError:
            return None, None

    def holder(self) -> int | None:
        """The PID of the live process holding the lock, or None when nobody does."""
        pid, start = self._recorded()
        if self.held:
            return pid
        try:
            fd = os.open(self.path, os.O_RDWR)
        except OSError:
            return None
        try:
            got = _try_os_lock(fd)
        finally:
            os.close(fd)  # closing drops a lock this probe took
        if got is None:
            return pid if pid is not None and _same_process(pid, start) else None
        return None if got else pid

    # ---- taking and giving back ------------------------------------------------------------------
    def acquire(self) -> None:
        for attempt in range(20):
            if self._try_acquire(last_look=attempt >= BUSY_TRIES):
                return
        raise RacerlabError(f"{self.path}: could not take the training lock; another trainer keeps taking it. "
                            "Stop the other trainer, then train again")

    def _refuse(self):
        pid = self.holder() or self._recorded()[0]
        who = f"process {pid}" if pid else "another process"
        fix = f"stop it first (kill {pid})" if pid and pid != os.getpid() else "stop it first"
        raise RacerlabError(f"{self.path}: the model is being trained by {who}; {fix} or train a clone "
                            "(`racerlab clone`)") from None

    def _try_acquire(self, last_look: bool) -> bool:
        try:
            fd, created = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644), True
        except FileExistsError:
            try:
                fd, created = os.open(self.path, os.O_RDWR), False
            except FileNotFoundError:  # released meanwhile
                return False
        try:
            got = _try_os_lock(fd)
        except BaseException:
            os.close(fd)
            raise
        if got is None:  # no OS file locks here: the file we created exclusively is the lock
            if created:
                os.write(fd, self._record())
                self._exclusive, self.held = True, True
            os.close(fd)
            return created or self._try_exclusive()
        if not got:
            os.close(fd)
            if not last_look:  # maybe only a look by `holder()` (the console's): it lets go at once
                time.sleep(BUSY_WAIT_S)
                return False
            self._refuse()
        try:  # the file may have been released (unlinked) between our open and our lock: lock the live one
            same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
        except FileNotFoundError:
            same = False
        if not same:
            os.close(fd)
            return False
        os.ftruncate(fd, 0)
        os.write(fd, self._record())
        self._fd, self.held = fd, True
        return True

    def _record(self) -> bytes:
        return f"{os.getpid()} {process_start(os.getpid()) or '-'} {time.time():.0f}\n".encode()

    def _try_exclusive(self) -> bool:
        """The fallback without OS file locks: create the file exclusively; recover a stale one by PID and
        start time, moving it aside under a unique name so that only one taker removes it."""
        try:
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            pid, start = self._recorded()
            if pid is not None and _same_process(pid, start):
                self._refuse()
            if pid is None and _age_s(self.path) < FRESH_S:  # just created; its taker is writing its PID
                time.sleep(BUSY_WAIT_S)
                return False
            aside = self.path.with_name(f"{self.path.name}.stale-{os.getpid()}-{time.monotonic_ns()}")
            try:
                os.rename(self.path, aside)
            except FileNotFoundError:
                return False
            if _parse(aside.read_bytes()) != (pid, start):  # taken between our read and our move: put it back
                try:
                    os.link(aside, self.path)
                except FileExistsError:
                    pass
            aside.unlink(missing_ok=True)
            return False  # try again: create ours, or meet the live one
        os.write(fd, self._record())
        os.close(fd)
        self._exclusive, self.held = True, True
        return True

    def release(self) -> None:
        if not self.held:
            return
        if self._exclusive:
            if self._recorded()[0] == os.getpid():
                self.path.unlink(missing_ok=True)
        else:  # unlink while still locked, then unlock: a waiter that opened the old file notices and retries
            self.path.unlink(missing_ok=True)
            os.close(self._fd)
        self._fd, self.held, self._exclusive = None, False, False

    def __enter__(self) -> TrainingLock:
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def _age_s(path: Path) -> float:
    try:
        return time.time() - path.stat().st_mtime
    except OSError:
        return FRESH_S

def _parse(data: bytes) -> tuple[int | None, str | None]:
    parts = data.decode(errors="replace").split()
    try:
        return int(parts[0]), parts[1] if len(parts) > 1 and parts[1] != "-" else None
    except (ValueError, IndexError):
        return None, None
