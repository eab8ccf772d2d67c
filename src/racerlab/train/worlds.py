"""The worlds a training drives, built from a model's settings for anyone who trains: the local trainer and
a cluster's rollout workers build exactly the same worlds from the same `training.toml`.

`WorldBuilder` makes one `World` of the run's observation, start rules, episode cap, race and reward;
`training_worlds` spreads the cars over the tracks (named or generated); `evaluation_world` is the in-training
evaluation's. `LocalCollection` is the trainer's default collection: those worlds on this machine.

Seeds, named once: training world k of generated-track draw d runs with seed `run.seed + DRAW_SEED_STRIDE * d
+ k`, the evaluation world with EVAL_SEED (apart from every training world's), and draw d's generated tracks
come from `run.seed * GENERATED_SEED_FACTOR + d`.
"""

from __future__ import annotations

from racerlab.errors import ConfigError, TrackError
from racerlab.model import as_model_metadata
from racerlab.sim import StartRules, World
from racerlab.track import load as load_track
from racerlab.train.rollout import Collector, Rollout

EVAL_SEED = 10_007
DRAW_SEED_STRIDE = 1_000
GENERATED_SEED_FACTOR = 7_919


def start_rules(track) -> StartRules:
    """The start rules of a `[track]` table (`model.config.TrackSettings`)."""
    return StartRules(change_start=track.change_start, advance=track.round_robin_advance, offset=track.start_offset,
                      reverse=track.reverse, alternate_direction=track.alternate_direction)


def generated_tracks(settings, seed: int, draw: int) -> list:
    """The generated training tracks of draw number `draw` (none unless `track.generated` is set)."""
    if not settings.generated:
        return []
    from racerlab.track.generate import generate_many

    return generate_many(seed * GENERATED_SEED_FACTOR + draw, settings.generated,
                         (settings.generated_min_length, settings.generated_max_length),
                         (settings.generated_min_width, settings.generated_max_width), settings.generated_min_radius,
                         prefix=f"generated_{draw}")


class WorldBuilder:
    """Worlds of one run: `cfg` (a `TrainingConfig` with the flags applied), the model's metadata and its reward
    (a `RewardCaller`, a callable or None). `track_flag` says the tracks came from --track (for the errors)."""

    def __init__(self, cfg, metadata, reward, *, track_flag: bool = False):
        self.cfg = cfg
        self.metadata = metadata
        self.reward = reward
        self.track_flag = track_flag

    def load_track(self, name):
        """A named track; a name that does not load is a one-line error naming where it was given."""
        try:
            return load_track(name)
        except TrackError as exc:
            where = "--track" if self.track_flag else f"{self.cfg.source}: track.names"
            raise TrackError(f"{where}: {exc}") from None

    def check_tracks(self) -> None:
        """Load every named track once, so a bad name fails here rather than inside a remote worker."""
        for name in self.cfg.track.names:
            self.load_track(name)

    def world(self, track, cars: int, seed: int, randomise=None, training: bool = True) -> World:
        run = self.cfg.run
        track = self.load_track(track) if isinstance(track, str) else track
        # the [car] table's simulator car; its steps jitter in training, not in the evaluation (a lucky draw of
        # short steps would otherwise count as a faster lap), unless the table says (`CarSettings.params`)
        car = self.cfg.car.params(as_model_metadata(self.metadata).version, training=training)
        return World(track, cars, self.metadata, self.reward, run.observation, start=start_rules(self.cfg.track),
                     max_episode_steps=run.max_episode_steps, reward_order=run.reward_order, seed=seed,
                     race=self.cfg.race, randomise=randomise, look=run.look, car=car)

    def car_counts(self, tracks: int) -> list[int]:
        """Cars per track: `run.num_cars` spread evenly; a head_to_model race gives every track whole pairs."""
        n = self.cfg.run.num_cars
        if not self.cfg.race.head_to_model:
            return [n // tracks + (1 if k < n % tracks else 0) for k in range(tracks)]
        if n % 2 or n < 2 * tracks:
            raise ConfigError(f"{self.cfg.source}: run.num_cars (or --cars) {n}: a head_to_model race pairs the "
                              f"cars, so it needs an even number, at least 2 per track "
                              f"({tracks} track{'s' if tracks != 1 else ''})")
        pairs = n // 2
        return [2 * (pairs // tracks + (1 if k < pairs % tracks else 0)) for k in range(tracks)]

    def training_worlds(self, draw: int = 0) -> list[World]:
        """One world per training track (generated draw `draw`, or the named tracks: all, or draw `draw`'s
        `track.at_once` of them) with its share of the cars."""
        cfg = self.cfg
        tracks = generated_tracks(cfg.track, cfg.run.seed, draw) or cfg.track.names_of_draw(draw)
        seed = cfg.run.seed + DRAW_SEED_STRIDE * draw
        return [self.world(t, c, seed + k, cfg.randomise)
                for k, (t, c) in enumerate(zip(tracks, self.car_counts(len(tracks)), strict=True))]

    def evaluation_cars(self) -> int:
        """Cars of the greedy evaluation world: one per evaluation episode; a head-to-model race pairs its cars,
        so an odd count gains one (each car still drives one judged episode)."""
        n = max(self.cfg.evaluation.episodes, 1)
        return n + n % 2 if self.cfg.race.head_to_model else n

    def evaluation_world(self) -> World:
        """The in-training evaluation's world, on the first named track (randomised only if `randomise.evaluation`)."""
        r = self.cfg.randomise
        return self.world(self.cfg.track.names[0], self.evaluation_cars(), EVAL_SEED,
                          randomise=r if r.evaluation else None, training=False)


class LocalCollection:
    """The trainer's collection on this machine: the training worlds, with new generated tracks (or the next
    `track.at_once` named ones) every `track.regenerate_every` iterations (the draw follows the iteration number,
    so a resumed run drives the tracks it would have driven).

    A collection is what `Trainer` collects through (the cluster passes its own): `collect(agent, target,
    max_steps, first_episode_number=, deadline=, tick=) -> Rollout`, `before_iteration(iteration)`, `state()`
    (what a checkpoint keeps to resume it), `restore(saved)`, `metrics(iteration)` (extra metrics.jsonl keys)
    and `close()`.
    """

    def __init__(self, builder: WorldBuilder):
        self.builder = builder
        self.draw = 0
        self.worlds = builder.training_worlds(self.draw)
        self.collector = Collector(self.worlds)

    def before_iteration(self, iteration: int) -> None:
        track = self.builder.cfg.track
        every = track.regenerate_every
        if not (track.generated or track.rotates) or not every or iteration // every == self.draw:
            return
        self.draw = iteration // every
        next_uid = self.collector.next_uid
        self.worlds = self.builder.training_worlds(self.draw)
        self.collector = Collector(self.worlds)
        self.collector.next_uid = next_uid

    def collect(self, agent, target_episodes: int, max_steps: int, first_episode_number: int = 0, *,
                deadline: float | None = None, tick=None, tick_s: float = 10.0) -> Rollout:
        return self.collector.collect(agent, target_episodes, max_steps, first_episode_number=first_episode_number,
                                      deadline=deadline, tick=tick, tick_s=tick_s)

    def state(self) -> dict:
        return {"starts": [w.sim.episodes_started for w in self.worlds]}

    def restore(self, saved: dict) -> None:
        for w, n in zip(self.worlds, saved.get("starts") or [], strict=False):
            w.sim.episodes_started = int(n)

    def metrics(self, iteration: int) -> dict:
        return {}

    def close(self) -> None:
        pass
