"""League evaluations on a Ray cluster: `racerlab league serve DIR --ray ADDRESS` (`pip install 'racerlab[cluster]'`).

`RayPool(folder, url, address, workers)` is `WorkerPool`'s counterpart: the queue stays on the server. A dispatcher
thread claims submissions (`racerlab.league.queue`) as a local worker does, renews each claim's lease while its Ray
task runs (`worker._Beat`) and sends the task everything it needs as data: the stored model's files, the claim (its
rules JSON and hash) and the pinned track, so a node needs neither the database nor the league folder, only the
same racerlab, torch and NumPy (checked: a node with other versions would race other floating-point sums). The
task (`league_evaluation`) runs with the evaluation's pinned environment (`evaluation.PIN_ENV`, set by Ray before
the worker process starts, so before torch loads), evaluates into a scratch folder laid out as the league folder
(`worker.evaluate_in`, the code a local worker runs) and returns the outcome and the evaluation's files, which the
dispatcher writes into results/<id>/attempt-<n>/ where a local worker writes them, then stores the outcome.

A Ray worker or node lost mid-evaluation (killed, out of memory, the machine gone) hands its claim back as a local
worker killed with -9 does (`queue.reap`: evaluated again from the start once, then failed with the reason). A node
that cannot evaluate (racerlab missing there, other versions) gives the submission back without counting it and the
server prints one line naming the node. At most `workers` tasks run at once; by default the cluster's CPUs, read
again as machines join or leave.
"""

from __future__ import annotations

import importlib.util
import os
import secrets
import socket
import sys
import threading
import time
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

from racerlab import __version__
from racerlab.errors import RacerlabError
from racerlab.league import queue
from racerlab.league.store import Store
from racerlab.league.worker import POLL_S, SEEN_EVERY_S, _Beat, attempt_folder, reap_dead_local
from racerlab.logs import atomic_write_bytes

PROBE_S = 5.0  # a head that does not accept a TCP connection within this is not there
GET_S = 120.0  # fetching a finished task's answer (its files) from the object store, at most
PAUSE_S = 10.0  # after a node could not evaluate, before the next claim: its one line is not repeated every second
NODE_HOLD_S = 180.0  # after a node died, claims wait until Ray's node table changes, at most this long
SAY_AGAIN_S = 60.0  # the same trouble of the dispatcher is printed again after this
VERSIONED = ("torch", "numpy")  # besides racerlab: the builds whose sums an evaluation depends on


def versions() -> dict[str, str]:
    """The versions an evaluation's bits depend on, on this machine."""
    return {"racerlab": __version__, **{name: metadata.version(name) for name in VERSIONED}}


def pinned_env() -> dict[str, str]:
    """The environment a local worker evaluates with (`pin_environment`: PIN_ENV where the server has not chosen)."""
    from racerlab.league.evaluation import PIN_ENV

    return {key: os.environ.get(key, value) for key, value in PIN_ENV.items()}


def check_address(address: str) -> tuple[str, int]:
    """(host, port) of a Ray head's address HOST:PORT (or ray://HOST:PORT); one line when it is not one."""
    text = address.removeprefix("ray://")
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise RacerlabError(f"--ray {address}: give the Ray head's address as HOST:PORT (`ray start --head` prints "
                            "it, e.g. 10.0.0.5:6379)")
    return host.strip("[]"), int(port)


def join_cluster(address: str):
    """Ray, connected to the cluster at `address`; one line when Ray is missing or no cluster answers there."""
    if importlib.util.find_spec("ray") is None:  # not imported here: cluster.collector imports it
        raise RacerlabError(f"--ray {address}: Ray is not installed; run `pip install 'racerlab[cluster]'`")
    host, port = check_address(address)
    why = _not_grpc(host, port)
    if why:  # ray.init would retry for many minutes on an address where no Ray head answers
        raise RacerlabError(f"--ray {address}: no Ray cluster answers there ({why}); start its head with "
                            "`ray start --head` and give the address it prints") from None
    from racerlab.cluster.collector import connect

    try:
        return connect(address)
    except RacerlabError:
        raise
    except Exception as exc:  # noqa: BLE001 - Ray's own errors (authentication, versions) as one line
        first = (str(exc).strip().splitlines() or [""])[0][:300]
        raise RacerlabError(f"--ray {address}: could not join the Ray cluster ({type(exc).__name__}: {first})") \
            from None


# an HTTP/2 client's first bytes: the connection preface and an empty SETTINGS frame
_H2_HELLO = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])


def _not_grpc(host: str, port: int) -> str:
    """Why nothing at host:port can be a Ray head ('' when it may be): a Ray head's GCS is a gRPC server, which answers
    an HTTP/2 preface with a SETTINGS frame at once; a closed port, a web server or silence does not."""
    try:
        with socket.create_connection((host, port), timeout=PROBE_S) as conn:
            conn.sendall(_H2_HELLO)
            head = conn.recv(9)
    except OSError as exc:
        return exc.strerror or type(exc).__name__
    if len(head) == 9 and head[3] == 4:  # a frame header whose type is SETTINGS
        return ""
    return "something answers, but not a Ray head's gRPC" if head else "the connection was closed without an answer"


# ---- what travels -----------------------------------------------------------------------------------------------
def make_job(store: Store, claim: queue.Claim, out: Path) -> dict:
    """Everything a node needs to evaluate `claim` into `out` (inside the league folder), as data."""
    from racerlab.league.rules import Rules

    model_dir = store.model_dir(claim.model_hash)
    model = {p.name: p.read_bytes() for p in sorted(model_dir.glob("*")) if p.is_file()}
    track = store.folder / "tracks" / f"{Rules.from_json(claim.rules_json).driven_track[1]}.npy"
    # a missing track fails the evaluation with load_pinned's line, as on a local worker
    return {"claim": claim, "model": model, "track": (track.name, track.read_bytes()) if track.is_file() else None,
            "out": str(out.relative_to(store.folder)), "versions": versions()}


def league_evaluation(job: dict) -> dict:
    """The Ray task: the job's evaluation in a scratch folder laid out as the league folder; the outcome and the
    evaluation folder's files (relative path: bytes)."""
    from racerlab.league.worker import evaluate_in
    from racerlab.logs.scratch import scratch_dir

    here = versions()
    if here != job["versions"]:
        differ = ", ".join(f"{k} {here.get(k)} here, {v} on the server" for k, v in job["versions"].items()
                           if here.get(k) != v)
        raise RacerlabError(f"Ray node {socket.gethostname()}: {differ}; install the server's versions on every node")
    tracks = _tracks_dir()
    track = tracks / Path(job["track"][0]).name if job["track"] is not None else None
    if track is not None and not track.is_file():  # load_pinned checks its hash
        atomic_write_bytes(track, job["track"][1])
    with scratch_dir("league-ray") as root:
        model_dir = root / "models" / job["claim"].model_hash
        model_dir.mkdir(parents=True)
        for name, data in job["model"].items():
            (model_dir / Path(name).name).write_bytes(data)
        out = root / job["out"]
        status, reason, values = evaluate_in(root, job["claim"], out, tracks_dir=tracks)
        files = {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()} \
            if out.is_dir() else {}
        return {"status": status, "reason": reason, "values": values, "files": files, "root": str(root)}


_TRACKS: list[Path] = []


def _tracks_dir() -> Path:
    """This Ray worker process's pinned tracks, kept while it lives: `load_pinned` keeps one Track object per track
    and folder, so a camera's raster of it is built once per worker, as on a local worker. Swept by its PID after
    the process is gone (`logs.scratch`)."""
    if not _TRACKS:
        import atexit
        import shutil
        import tempfile

        from racerlab.logs.scratch import scratch_root, sweep

        root = scratch_root()
        sweep(root)
        _TRACKS.append(Path(tempfile.mkdtemp(prefix=f"league-ray-tracks-pid{os.getpid()}-", dir=root)))
        atexit.register(shutil.rmtree, _TRACKS[0], True)
    return _TRACKS[0]


def land(store: Store, out_rel: str, answer: dict) -> None:
    """A task's files written where a local worker writes them; the node's scratch folder named in its JSON files
    (summary.json's model_dir) becomes the league folder, as a local worker writes it."""
    out = store.path(out_rel)
    root, here = answer["root"].encode(), str(store.folder).encode()
    for rel, data in answer["files"].items():
        path = store.path(f"{out_rel}/{rel}")
        if out not in path.parents:
            raise RacerlabError(f"a Ray node answered with a file outside the evaluation folder: {rel}")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data.replace(root, here) if path.suffix == ".json" else data)


# ---- the dispatcher -----------------------------------------------------------------------------------------------
@dataclass
class Job:
    worker: str
    claim: queue.Claim
    beat: _Beat
    out: str


class RayPool:
    """Evaluations of one league's queue on the Ray cluster at `address`, `workers` at a time (default: its CPUs)."""

    def __init__(self, folder, url: str | None = None, address: str = "", workers: int | None = None, *,
                 lease_s: float = queue.LEASE_S, poll_s: float = POLL_S, note=None):
        if workers is not None and workers < 1:
            raise RacerlabError(f"--ray-workers must be at least 1, got {workers}")
        self.folder, self.url, self.address, self.fixed = str(Path(folder).resolve()), url, address, workers
        self.lease_s, self.poll_s = lease_s, poll_s
        self.note = note or (lambda line: print(f"racerlab league: {line}", file=sys.stderr, flush=True))
        self.jobs: dict = {}  # ObjectRef -> Job
        self.tag = f"{socket.gethostname()[:40]}:ray{os.getpid()}:{secrets.token_hex(2)}"
        self.slots: set[str] = set()  # every worker id the dispatcher used (the workers table's rows)
        self._stopping = threading.Event()
        self._resume_at = 0.0  # after a node could not evaluate: a pause before the next claim
        self._held: tuple[frozenset, float] | None = None  # after a node died: the live nodes then, and until when
        self._said, self._said_at = "", 0.0  # the dispatcher's last trouble, and when it said so
        self._thread: threading.Thread | None = None

    def start(self) -> RayPool:
        was = sys.modules.get("ray")
        self._owns_ray = not (was is not None and was.is_initialized())
        self.ray = join_cluster(self.address)
        self.store = Store.open(self.folder, self.url)
        reap_dead_local(self.store)  # a killed server's claims (its pid is in the workers table) go back now
        self.remote = self.ray.remote(num_cpus=1, max_retries=0, runtime_env={"env_vars": pinned_env()})(
            league_evaluation)
        self._seen = 0.0
        self._thread = threading.Thread(target=self._run, daemon=True, name="league-ray")
        self._thread.start()
        return self

    @property
    def capacity(self) -> int:
        if self.fixed:
            return self.fixed
        return int(self.ray.cluster_resources().get("CPU", 0))  # none (a head with --num-cpus=0 alone): no claims

    @property
    def evaluating(self) -> dict[str, int]:
        """The submissions under evaluation on the cluster, by the dispatcher's worker id."""
        return {job.worker: job.claim.submission_id for job in self.jobs.values()}

    def _run(self) -> None:
        while not self._stopping.is_set():
            try:
                self._fill()
                self._collect()
            except Exception as exc:  # noqa: BLE001 - a database or cluster hiccup: the leases have slack
                line = f"the Ray dispatcher: {type(exc).__name__}: {(str(exc).strip().splitlines() or [''])[0][:200]}"
                if line != self._said or time.monotonic() - self._said_at > SAY_AGAIN_S:  # not once a second
                    self.note(f"{line}; trying again")
                    self._said, self._said_at = line, time.monotonic()
                self._stopping.wait(self.poll_s)

    def _fill(self) -> None:
        capacity = self.capacity
        busy = {job.worker for job in self.jobs.values()}
        free = [w for w in (f"{self.tag}:{k}" for k in range(capacity)) if w not in busy]
        self.slots.update(free)
        if time.monotonic() - self._seen > SEEN_EVERY_S:
            for worker in free:
                queue.worker_seen(self.store, worker, socket.gethostname(), os.getpid(), "idle")
            self._seen = time.monotonic()
        if not free or time.monotonic() < self._resume_at:
            return
        # a claim only for a CPU free now: with a node just lost, the submission waits queued, not claimed for a task
        # that no node can run yet
        free = free[:self._cpus_free()]
        queue.reap(self.store)
        for worker in free:
            if self._stopping.is_set():
                return
            claim = queue.claim(self.store, worker, self.lease_s)
            if claim is None:
                return
            self._send(worker, claim)

    def _alive(self) -> dict[str, float]:
        """Ray's live nodes, by id, with their CPUs."""
        return {n["NodeID"]: n.get("Resources", {}).get("CPU", 0) for n in self.ray.nodes() if n.get("Alive")}

    def _cpus_free(self) -> int:
        """CPUs free now. The owner hears of a node's death (NodeDiedError) before Ray's node table and resource
        view do (tens of seconds on a busy machine, measured): until the table changes, a dead node's CPU still
        shows as free, and a claim for it would sit 'evaluating' in a task no node runs. So after a node died no
        claim is made until the live nodes differ from those of that moment (it is gone, or another joined)."""
        alive = self._alive()
        if self._held is not None:
            nodes, until = self._held
            if frozenset(alive) == nodes and time.monotonic() < until:
                return 0
            self._held = None
        free = int(self.ray.available_resources().get("CPU", 0))
        return max(0, min(free, int(sum(alive.values())) - len(self.jobs)))

    def _send(self, worker: str, claim: queue.Claim) -> None:
        queue.worker_seen(self.store, worker, socket.gethostname(), os.getpid(), "evaluating")
        out = attempt_folder(self.store, claim)
        ref = self.remote.remote(make_job(self.store, claim, out))  # if this raises, the lease runs out: reaped
        beat = _Beat(self.store, claim, self.lease_s)
        beat.start()
        self.jobs[ref] = Job(worker, claim, beat, str(out.relative_to(self.store.folder)))

    def _collect(self) -> None:
        if not self.jobs:
            self._stopping.wait(self.poll_s)
            return
        for ref, job in list(self.jobs.items()):
            if job.beat.lost.is_set():  # its lease ran out and another took it: the work is dropped
                self._drop(ref, cancel=True)
        if not self.jobs:
            return
        ready, _ = self.ray.wait(list(self.jobs), num_returns=1, timeout=self.poll_s)
        for ref in ready:
            self._answer(ref, self.jobs[ref])

    def _answer(self, ref, job: Job) -> None:
        try:
            self._store_answer(ref, job)
        finally:  # whatever happened (a full disk while writing), the task is done with: never waited on again
            self._drop(ref)

    def _store_answer(self, ref, job: Job) -> None:
        errors = self.ray.exceptions
        try:
            answer = self.ray.get(ref, timeout=GET_S)
        except (errors.RayTaskError, errors.RuntimeEnvSetupError) as exc:  # the node cannot evaluate: not the
            # submission's fault, not counted
            from racerlab.cluster.collector import remote_error

            self.note(f"submission {job.claim.submission_id} queued again: {remote_error(exc, 'a Ray node')}")
            queue.release(self.store, job.claim)
            self._resume_at = time.monotonic() + PAUSE_S
        except errors.RayError as exc:  # the worker or its node was lost: as a local worker killed with -9
            self.note(f"submission {job.claim.submission_id}: its Ray worker was lost ({type(exc).__name__}); "
                      "evaluated again from the start")
            queue.reap(self.store, dead_workers=(job.worker,))
            if isinstance(exc, errors.NodeDiedError):
                self._held = (frozenset(self._alive()), time.monotonic() + NODE_HOLD_S)
        else:
            if not job.beat.lost.is_set():
                land(self.store, job.out, answer)
                queue.finish(self.store, job.claim, answer["status"], answer["reason"], answer["values"])

    def _drop(self, ref, cancel: bool = False) -> None:
        job = self.jobs.pop(ref)
        job.beat.done.set()
        if cancel:
            self.ray.cancel(ref, force=True)
        queue.worker_seen(self.store, job.worker, socket.gethostname(), os.getpid(), "idle")

    def stop(self, timeout: float = 60.0) -> None:
        """Stop sending; evaluations under way are cancelled and given back to the queue without counting them."""
        self._stopping.set()
        if self._thread is not None:
            self._thread.join(timeout)
        for ref, job in list(self.jobs.items()):
            self._drop(ref, cancel=True)
            queue.release(self.store, job.claim)
        for worker in self.slots:
            queue.worker_seen(self.store, worker, socket.gethostname(), os.getpid(), "stopped")
        if self._owns_ray:
            self.ray.shutdown()
        self.store.dispose()
