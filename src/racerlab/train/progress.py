"""The live progress view of a training: one line per iteration, a summary at the end."""

from __future__ import annotations

import math
import sys


def _fmt_time(seconds: float | None) -> str:
    if seconds is None or math.isnan(seconds):
        return "--"
    seconds = int(round(seconds))
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m" if h else f"{m}m{s:02d}s"


def _lap(x) -> str:
    return "--" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.2f}s"


class Progress:
    """Prints to stdout (rich colours on a terminal, plain text otherwise); silent when disabled."""

    def __init__(self, enabled: bool = True):
        self.enabled = enabled
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
        if self.console is not None:
            self.console.print(text, style=style or None, highlight=False)
        else:
            print(text, flush=True)

    def note(self, text: str) -> None:
        self._print(text, "yellow")

    def tick(self, episodes: int, target: int, env_steps: int | None, seconds: float) -> None:
        """A long iteration's heartbeat (at least every 10 s while collecting)."""
        steps = "" if env_steps is None else f", {env_steps} env steps"  # None: not known yet (Ray workers)
        self._print(f"  collecting: {episodes}/{target} episodes ended{steps}, {seconds:.0f} s")

    def start(self, trainer, resumed: bool) -> None:
        cfg, meta = trainer.cfg, trainer.metadata
        what = f"resuming at iteration {trainer.state.iteration}" if resumed else "starting"
        tracks = ", ".join(cfg.track.names)
        self._print(f"training {trainer.folder.path} ({what}): {meta.training_algorithm} on {tracks}, "
                    f"{cfg.run.num_cars} cars, observation {trainer.worlds[0].observation.name}, "
                    f"device {trainer.agent.device}, car {trainer.worlds[0].sim.car_params.name}", "bold")
        limits = [f"{cfg.stop.minutes:g} min" if cfg.stop.minutes else "",
                  f"{cfg.stop.episodes} episodes" if cfg.stop.episodes else "",
                  f"{cfg.stop.iterations} iterations" if cfg.stop.iterations else ""]
        limits = [x for x in limits if x] or [f"{trainer.hp.term_cond_max_episodes} episodes (term_cond_max_episodes)"]
        self._print(f"stops after {' / '.join(limits)} or Ctrl-C (the last complete iteration is kept)")

    def iteration(self, e: dict, eta: float | None) -> None:
        ent = e.get("losses/entropy")
        ev = e.get("eval/mean_progress")
        self._print(
            f"it {e['iteration']:4d} | ep {e['episodes']:6d} | reward {e['charts/mean_reward']:8.2f} | "
            f"completion {e['charts/completion']:5.1f}% | eval {'--' if ev is None else f'{ev:5.1f}%'} | "
            f"best lap {_lap(e['best/lap_time'])} | entropy {'--' if ent is None else f'{ent:.3f}'} | "
            f"{e['charts/env_steps_per_s']:7.0f} steps/s | left {_fmt_time(eta)}")

    def finish(self, r) -> None:
        fl = r.first_lap
        first = (f"first eval lap at iteration {fl['iteration']} after {fl['wall_seconds']:.0f} s"
                 if fl else "no complete evaluation lap yet")
        self._print(f"stopped: {r.stopped or 'done'}. {r.iterations} iterations, {r.episodes} episodes, "
                    f"{r.env_steps} env steps in {_fmt_time(r.wall_seconds)}; best lap {_lap(r.best_lap_time)}; "
                    f"{first}; best checkpoint {r.best_checkpoint}", "bold green")
