"""The live progress view of a training: one line per iteration under a column header, a heartbeat while a
long phase runs (collection, the update, the evaluation episodes), a summary at the end. Every line fits 80
columns, so a terminal of the default width never wraps them."""

from __future__ import annotations

import math
import sys
import textwrap
import threading
import time
from contextlib import contextmanager
from pathlib import Path

from racerlab.logs import BEST_CHECKPOINT_RULES, BEST_LAP_NAME

WIDTH = 80
HEARTBEAT_S = 10.0  # a phase that runs longer than this says so, and again every HEARTBEAT_S
HEADER_EVERY = 25  # iteration lines between two column headers
# the iteration table: (header, width) per column; a row is the values in the same widths
COLUMNS = (("iter", 5), ("episodes", 8), ("reward", 8), ("train %", 7), ("eval %", 6), (BEST_LAP_NAME, 13),
           ("entropy", 7), ("steps/s", 7), ("left", 6))


def _fmt_time(seconds: float | None) -> str:
    if seconds is None or math.isnan(seconds):
        return "--"
    seconds = int(round(seconds))
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m" if h else f"{m}m{s:02d}s"


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")  # "stops after 1 iteration", not "1 iterations"


def _lap(x) -> str:
    return "--" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.2f}s"


class Progress:
    """Prints to stdout (rich colours on a terminal, plain text otherwise); silent when disabled. Keeps the run's
    notes (what it said besides the iteration lines) for its result."""

    def __init__(self, enabled: bool = True):
        self.enabled = enabled
        self.notes: list[str] = []
        self.rows = 0  # iteration lines printed, for the column header's repeats
        self.console = None
        if enabled and sys.stdout.isatty():
            try:
                from rich.console import Console

                self.console = Console()
            except ImportError:  # pragma: no cover - rich is a dependency
                self.console = None

    def _print(self, text: str, style: str = "") -> None:
        if not self.enabled:
            return
        text = "\n".join(textwrap.fill(line, WIDTH, subsequent_indent="  ", break_on_hyphens=False)
                         for line in text.split("\n"))
        if self.console is not None:
            self.console.print(text, style=style or None, highlight=False)
        else:
            print(text, flush=True)

    def note(self, text: str) -> None:
        self.notes.append(text)
        self._print(text, "yellow")

    @contextmanager
    def heartbeat(self, what: str):
        """While the block runs longer than HEARTBEAT_S, a line every HEARTBEAT_S says it is still running (a
        camera network's update took 68 s on 2 cores with nothing printed)."""
        if not self.enabled:
            yield
            return
        done = threading.Event()
        t0 = time.perf_counter()

        def beat():
            while not done.wait(HEARTBEAT_S):
                self._print(f"  {what}: {time.perf_counter() - t0:.0f} s so far")

        thread = threading.Thread(target=beat, name="racerlab-heartbeat", daemon=True)
        thread.start()
        try:
            yield
        finally:
            done.set()
            thread.join()

    def tick(self, episodes: int, target: int, env_steps: int | None, seconds: float) -> None:
        """A long iteration's heartbeat (at least every 10 s while collecting)."""
        steps = "" if env_steps is None else f", {env_steps} env steps"  # None: not known yet (Ray workers)
        self._print(f"  collecting: {episodes}/{target} episodes ended{steps}, {seconds:.0f} s")

    def start(self, trainer, resumed: bool) -> None:
        cfg, meta = trainer.cfg, trainer.metadata
        what = f"resuming at iteration {trainer.state.iteration}" if resumed else "starting"
        tracks = _tracks_said(cfg.track)
        if cfg.track.generated:  # names then hold the evaluation track only
            again = f", redrawn every {cfg.track.regenerate_every} iterations" if cfg.track.regenerate_every else ""
            tracks = f"{cfg.track.generated} generated circuits{again} (evaluated on {tracks})"
        self._print(f"training {trainer.folder.path} ({what}): {meta.training_algorithm} on {tracks}, "
                    f"{cfg.run.num_cars} cars, observation {trainer.eval_world.observation.name}, "
                    f"device {trainer.agent.device}, car {trainer.eval_world.sim.car_params.name}", "bold")
        limits = [f"{cfg.stop.minutes:g} min" if cfg.stop.minutes else "",
                  _count(cfg.stop.episodes, "episode") if cfg.stop.episodes else "",
                  _count(cfg.stop.iterations, "iteration") if cfg.stop.iterations else ""]
        limits = [x for x in limits if x] or [f"{trainer.hp.term_cond_max_episodes} episodes (term_cond_max_episodes)"]
        self._print(f"stops after {' / '.join(limits)} or Ctrl-C (the last complete iteration is kept)")
        self._print(f"{BEST_LAP_NAME}: the fastest lap of the greedy evaluation episodes so far\n"
                    "train %, eval %: mean progress of the training and of the evaluation episodes")

    def iteration(self, e: dict, eta: float | None) -> None:
        if self.rows % HEADER_EVERY == 0:
            self._print(" ".join(h.rjust(w) for h, w in COLUMNS))
        self.rows += 1
        ent = e.get("losses/entropy")
        ev = e.get("eval/mean_progress")
        values = (str(e["iteration"]), str(e["episodes"]), f"{e['charts/mean_reward']:.2f}",
                  f"{e['charts/completion']:.1f}", "--" if ev is None else f"{ev:.1f}", _lap(e["best/lap_time"]),
                  "--" if ent is None else f"{ent:.3f}", f"{e['charts/env_steps_per_s']:.0f}", _fmt_time(eta))
        self._print(" ".join(v.rjust(w) for v, (_, w) in zip(values, COLUMNS, strict=True)))

    def finish(self, r) -> None:
        fl = r.first_lap
        first = (f"first eval lap at iteration {fl['iteration']} after {fl['wall_seconds']:.0f} s"
                 if fl else "no complete evaluation lap yet")
        it = getattr(r, "best_lap_iteration", None)
        best = _lap(r.best_lap_time) + (f" (iteration {it})" if it is not None and not math.isnan(r.best_lap_time)
                                        else "")
        rule = BEST_CHECKPOINT_RULES.get(getattr(r, "best_rule", ""), "")
        self._print(f"stopped: {r.stopped or 'done'}. {r.iterations} iterations, {r.episodes} episodes, "
                    f"{r.env_steps} env steps in {_fmt_time(r.wall_seconds)}\n{BEST_LAP_NAME} {best}; {first}\n"
                    f"best checkpoint {r.best_checkpoint}" + (f", picked by {rule}" if rule else ""), "bold green")


def _tracks_said(t) -> str:
    """The named tracks in a few words: all of them up to 4, else the count and the first (the evaluation's)."""
    names = [Path(str(n)).stem if "/" in str(n) else str(n) for n in t.names]
    said = ", ".join(names) if len(names) <= 4 else f"{len(names)} tracks ({names[0]}, {names[1]}, ...)"
    if t.rotates and t.regenerate_every:
        said += f", {t.at_once} at a time, the next every {t.regenerate_every} iterations"
    return said
