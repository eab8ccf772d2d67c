"""The console's workspace: a folder whose sub-folders are model folders, their state, and the training
processes it starts.

A training is `racerlab train MODEL` in a process of its own (a new session, so closing the console or
its terminal does not stop it). Its pid and command are kept in `<workspace>/.console/<model>/training.json`;
a console started later finds it there and reattaches. Stop sends SIGINT, which `racerlab train` handles
as Ctrl-C: the last complete iteration is saved.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from racerlab import logs
from racerlab.console.modelapi import ModelFolder
from racerlab.console.security import ConsoleError, check_name, inside
from racerlab.errors import RacerlabError

STATE_DIR = ".console"
TAIL_BYTES = 64 * 1024
OUTPUT_DIR = "racerlab-out"  # where `racerlab quickstart` puts its model: the models in it are listed too
MODEL_ONLY = ("reward_function.py", "training.toml", "hyperparameters.json", "checkpoints")


def is_model_folder(path: Path) -> bool:
    """model_metadata.json and something only a model folder has: a `racerlab line` output folder holds a
    model_metadata.json (the fitted action space) and nothing else of a model, and is not one."""
    return (path / "model_metadata.json").is_file() and any((path / name).exists() for name in MODEL_ONLY)


def _pid_alive(pid: int, folder: Path) -> bool:
    """True while `pid` runs `racerlab train` on `folder` (a reused pid of another program is not ours)."""
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, PermissionError):
        return False
    proc = Path(f"/proc/{pid}")
    if proc.is_dir():
        try:
            if (proc / "stat").read_text().split(") ", 1)[1].startswith("Z"):
                return False
            cmd = (proc / "cmdline").read_bytes().split(b"\0")
        except OSError:
            return False
        return b"train" in cmd and str(folder).encode() in cmd
    return True


@dataclass
class Task:
    """A job the console runs in a thread of its own (evaluation, race, report, racing line, analysis)."""

    kind: str
    key: str
    status: str = "running"  # running | done | failed | cancelled
    message: str = ""
    result: dict = field(default_factory=dict)
    started: float = field(default_factory=time.time)
    finished: float | None = None
    cancel: threading.Event | None = None  # set to stop the job (a race), for those that can stop
    models: tuple[str, ...] = ()  # the model folders it reads and writes: none may be deleted while it runs

    def to_json(self) -> dict:
        return {"kind": self.kind, "key": self.key, "status": self.status, "message": self.message,
                "result": self.result, "started": self.started, "finished": self.finished,
                "cancellable": self.cancel is not None and self.status == "running",
                "cancelling": self.cancel is not None and self.cancel.is_set() and self.status == "running"}


class Workspace:
    def __init__(self, root):
        self.root = Path(root).resolve()
        self.root.mkdir(parents=True, exist_ok=True)
        self.state_root = self.root / STATE_DIR
        self._children: dict[str, subprocess.Popen] = {}
        self.tasks: dict[str, Task] = {}
        self._lock = threading.Lock()

    # ---- models ------------------------------------------------------------------------------
    def model_path(self, name: str) -> Path:
        """The folder of model `name`: `<workspace>/<name>`, or `<workspace>/racerlab-out/<name>` (the quickstart's
        model) when only that one is a model folder."""
        path = inside(self.root, name)
        if not is_model_folder(path):
            nested = inside(self.root, OUTPUT_DIR, name)
            if is_model_folder(nested):
                return nested
        return path

    def folder(self, name: str, must_exist: bool = True) -> ModelFolder:
        path = self.model_path(name)
        if must_exist and not is_model_folder(path):
            raise ConsoleError(f"{name}: no such model in {self.root}", 404)
        return ModelFolder(path)

    def model_names(self) -> list[str]:
        """Model folders in the workspace and in its racerlab-out/ (a name in both is the workspace's); a linked
        folder is not listed (nor served)."""
        names = set()
        for parent in (self.root, self.root / OUTPUT_DIR):
            if parent.is_dir():
                names.update(p.name for p in parent.iterdir()
                             if p.is_dir() and not p.is_symlink() and not p.name.startswith(".") and is_model_folder(p))
        return sorted(names)

    def summary(self, name: str) -> dict:
        folder = self.folder(name)
        out = {"name": name, "state": self.state(name), "track": None, "sensor": None, "algorithm": None,
               "action_space": None, "best_lap": None, "best_lap_iteration": None, "best_checkpoint": None,
               "best_rule": None, "iteration": 0, "episodes": 0, "error": None,
               "folder": str(folder.path.relative_to(self.root))}
        try:
            meta = folder.metadata()
            out.update(sensor=list(meta.sensor), algorithm=meta.training_algorithm,
                       action_space=meta.action_space_type)
            cfg = folder.config()
            out["track"], out["best_rule"] = list(cfg.track.names), logs.BEST_CHECKPOINT_RULES.get(
                cfg.evaluation.best_model_metric)
        except RacerlabError as exc:
            out["error"] = str(exc)
        last = logs.last_metrics_entry(logs.metrics_jsonl_path(folder.path))
        if last:
            best = logs.best_eval_lap([last])  # "best lap" as everywhere: racerlab.logs.BEST_LAP_MEANING
            out.update(iteration=last.get("iteration", 0), episodes=last.get("episodes", 0),
                       best_lap=best[0] if best else None, best_lap_iteration=best[1] if best else None,
                       best_checkpoint=last.get("best/checkpoint"))
        out["evaluations"] = [p.name for p in logs.evaluation_dirs(folder.path)]
        return out

    def delete(self, name: str) -> None:
        """Remove a model folder, holding its training lock meanwhile (a trainer started from a terminal or the
        cluster holds it too, so its folder is refused, not half-removed); the folder is first moved aside in
        one rename, so it is either whole or gone."""
        folder = self.folder(name)
        lock = folder.lock()
        with self._lock:  # no task that uses the model starts between the check and the move
            state = self.state(name)
            if state == "racing":
                raise ConsoleError(f"{name}: a running race uses it; cancel the race or wait for it to end, then "
                                   "delete", 409)
            if state != "idle":
                raise ConsoleError(f"{name}: stop its {state} first", 409)
            try:
                lock.acquire()
            except RacerlabError as exc:
                raise ConsoleError(f"{name}: training in another process; stop it first ({exc})", 409) from None
            try:
                self.state_root.mkdir(parents=True, exist_ok=True)
                trash = Path(tempfile.mkdtemp(prefix=f"deleting-{name}-", dir=self.state_root))
                os.replace(folder.path, trash / name)
            finally:
                lock.release()
        shutil.rmtree(trash, ignore_errors=True)
        shutil.rmtree(self.state_root / name, ignore_errors=True)

    # ---- state -------------------------------------------------------------------------------
    def state(self, name: str) -> str:
        if self.training_pid(name):
            return "training"
        task = self.tasks.get(f"evaluate:{name}")
        if task and task.status == "running":
            return "evaluating"
        if any(t.status == "running" and name in t.models for t in list(self.tasks.values())):
            return "racing"
        return "idle"

    def _training_file(self, name: str) -> Path:
        return self.state_root / check_name(name) / "training.json"

    def training_log(self, name: str) -> Path:
        return self.state_root / check_name(name) / "training.log"

    def training_pid(self, name: str) -> int | None:
        child = self._children.get(name)
        if child is not None and child.poll() is not None:
            self._children.pop(name, None)  # reaped: an exited child is no longer training
        try:
            info = json.loads(self._training_file(name).read_text())
            pid = int(info.get("pid", 0))
        except (OSError, ValueError, TypeError, AttributeError):
            pid = 0
        if pid > 0 and _pid_alive(pid, self.model_path(name)):
            return pid
        return self.folder(name, must_exist=False).lock().holder()  # a trainer started elsewhere (CLI, cluster)

    # ---- training ----------------------------------------------------------------------------
    def start_training(self, name: str, minutes=None, episodes=None, iterations=None) -> int:
        folder = self.folder(name)
        with self._lock:
            if self.state(name) != "idle":
                raise ConsoleError(f"{name}: already {self.state(name)}", 409)
            cmd = [sys.executable, "-m", "racerlab", "train", str(folder.path)]
            for flag, value in (("--minutes", minutes), ("--episodes", episodes), ("--iterations", iterations)):
                if value is not None:
                    cmd += [flag, str(value)]
            log = self.training_log(name)
            log.parent.mkdir(parents=True, exist_ok=True)
            with open(log, "ab") as out:
                out.write(f"\n$ racerlab train {name} {' '.join(cmd[5:])}\n".encode())
                out.flush()
                child = subprocess.Popen(cmd, cwd=self.root, stdout=out, stderr=subprocess.STDOUT,
                                         stdin=subprocess.DEVNULL, start_new_session=True)
            self._children[name] = child
            logs.atomic_write_json(self._training_file(name), {"pid": child.pid, "command": cmd,
                                                               "started": time.time()})
            return child.pid

    def stop_training(self, name: str) -> bool:
        """SIGINT, as Ctrl-C: the trainer saves its last complete iteration and exits."""
        pid = self.training_pid(name)
        if pid is None:
            return False
        os.kill(pid, signal.SIGINT)
        return True

    def log_tail(self, name: str, lines: int = 40) -> str:
        try:
            with open(self.training_log(name), "rb") as f:
                f.seek(0, os.SEEK_END)
                f.seek(max(f.tell() - TAIL_BYTES, 0))
                text = f.read().decode("utf-8", "replace")
        except OSError:
            return ""
        return "\n".join(text.splitlines()[-lines:])

    # ---- background tasks --------------------------------------------------------------------
    def run_task(self, kind: str, key: str, fn, cancel: threading.Event | None = None, models=()) -> Task:
        """Run `fn()` (returning a dict) in a thread; one task per key at a time. `cancel` is the event `fn` watches
        to stop early (`cancel_task` sets it); an error after it was set ends the task as "cancelled". `models`
        (names) are the model folders it uses: they cannot be deleted while it runs, nor can a deleted one be used."""
        with self._lock:
            old = self.tasks.get(key)
            if old and old.status == "running":
                raise ConsoleError(f"{key}: already running", 409)
            for name in models:
                self.folder(name)  # deleted meanwhile: 404, not a race that re-creates its folder
            task = self.tasks[key] = Task(kind, key, cancel=cancel, models=tuple(models))

        def work():
            try:
                task.result = fn() or {}
                task.status = "done"
            except RacerlabError as exc:
                stopped = cancel is not None and cancel.is_set()
                task.status, task.message = "cancelled" if stopped else "failed", str(exc)
            except Exception as exc:  # noqa: BLE001 - shown in the page rather than lost in a thread
                task.status, task.message = "failed", f"{type(exc).__name__}: {exc}"
            task.finished = time.time()

        threading.Thread(target=work, name=f"console-{key}", daemon=True).start()
        return task

    def cancel_task(self, key: str) -> Task:
        """Ask the running task `key` to stop; it ends at its next check (a race: the end of a lap)."""
        task = self.tasks.get(key)
        if task is None:
            raise ConsoleError(f"no task {key!r}", 404)
        if task.status != "running":
            raise ConsoleError(f"{key}: not running ({task.status})", 409)
        if task.cancel is None:
            raise ConsoleError(f"{key}: a {task.kind} cannot be cancelled; wait for it to end", 409)
        task.cancel.set()
        return task
