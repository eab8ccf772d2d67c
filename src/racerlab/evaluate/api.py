"""`evaluate(model_dir)`: a model folder's checkpoint driven under race rules, with its logs and result.

Opens the checkpoint (best by default, as simapp's EVAL_CHECKPOINT) through `ModelFolder.open`, which
refuses one that cannot be read, holds non-finite weights or does not match the folder's
model_metadata.json; builds a one-car world on the chosen track (the model's training track by
default; any track works for every sensor, since observations are computed from the track's
geometry) and drives greedy actions under `RaceRules`. Writes, in a new
`<model>/evaluation-<YYYYmmddHHMMSS>/` folder (the DRfC layout deepracer-utils reads, see
`racerlab.logs`): `evaluation-simtrace/0-iteration.csv`, `EvalMetrics.json`, `summary.json` and,
when asked, `evaluation.mp4`.

Rules are judged in AWS order (`reward_order="aws"`) whatever the training used, so that every
model is timed the same way.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from racerlab import logs
from racerlab.errors import RacerlabError
from racerlab.evaluate.results import (
    DEFAULT_RANKING_LAPS,
    Lap,
    RaceResult,
    counted,
    lap_table,
    race_result,
    result_lines,
)
from racerlab.evaluate.rules import RaceRules
from racerlab.evaluate.runner import EvalRun, run_evaluation, run_head_to_model
from racerlab.model import ModelFolder, OpenModel, resolve_track
from racerlab.spec import MAX_SPEED, RaceConfig

HUD_MIN_TOP_SPEED = 0.5  # m/s: a slow model's speed bar still spans this much
RACE_SEED = 0  # every race draws the same random stream (boxes, bots, randomisation): results repeat
VIDEO_WIDTH_PX = 960  # the track picture's width in an evaluation's video

SUMMARY_NAME = "summary.json"
VIDEO_NAME = "evaluation.mp4"


@dataclass
class EvaluationResult:
    """One model's evaluation: its laps, race numbers and where the files are."""

    model: str  # the model folder's name
    model_dir: Path
    checkpoint: str
    track: str
    rules: RaceRules
    laps: list[Lap]
    result: RaceResult
    out_dir: Path | None = None
    files: dict[str, Path] = field(default_factory=dict)  # simtrace, eval_metrics, summary, video
    steps: int = 0
    wall_seconds: float = 0.0
    run: EvalRun | None = field(default=None, repr=False)
    race: dict | None = None  # the [race] table the evaluation drove (summary.json "race")
    randomise: dict | None = None  # the [randomise] options (or speed mapping) driven under, those set only
    car: str = ""  # which car drove (`CarParams.name`)

    @property
    def text(self) -> str:
        """The result in the league's words."""
        return self.result.text

    def header(self) -> str:
        r = self.rules
        mode = "continuous" if r.continuous else "separate"
        direction = ", reversed" if r.reverse else ""
        if self.randomise:
            direction += ", randomised (" + ", ".join(f"{k} {v:g}" for k, v in self.randomise.items()) + ")"
        car = f", car: {self.car}" if self.car else ""
        return (f"{self.model} ({self.checkpoint}) on {self.track}{direction}: {counted(r.trials, 'trial')}, "
                f"{mode} laps, off-track penalty {r.off_track_penalty:g} s, up to {r.max_resets} resets{car}")

    def table(self) -> str:
        return lap_table(self.laps)

    def report(self) -> str:
        """Header, the lap table and the result lines, as the command prints them."""
        return "\n".join([self.header(), self.table(), *result_lines(self.result)])

    def summary(self) -> dict:
        return {
            "model": self.model, "model_dir": str(self.model_dir), "checkpoint": self.checkpoint,
            "track": self.track, "rules": self.rules.to_json(), "result": self.result.to_json(),
            "laps": [lap.to_json() for lap in self.laps], "steps": self.steps,
            "wall_seconds": round(self.wall_seconds, 3), "race": self.race,
            "files": {k: str(v.relative_to(self.out_dir)) for k, v in self.files.items()} if self.out_dir else {},
            "randomise": self.randomise, "car": self.car,
            "created": datetime.now().isoformat(timespec="seconds"),
        }


# ---- the model's policy -------------------------------------------------------------------------------
# A model is opened through `ModelFolder.open` (its checks: `racerlab.model.opened`); its policy comes from
# `racerlab.agent.inference_policy`, as every other reader's does.


def make_policy(model: OpenModel, world, device: str = "cpu"):
    """Greedy actions of the checkpoint's agent (argmax for discrete, the mean for continuous, as AWS)."""
    from racerlab.agent import inference_policy

    _check_features_width(model, world)
    return inference_policy(world.observation.space, model.metadata, model.state.agent, where=model.path,
                            hyperparameters=model.hyperparameters, device=device)


def _input_width(policy_state: dict) -> int | None:
    """Columns of the first weight matrix of a features policy (its MLP's input width); None for other networks."""
    for value in policy_state.values():
        shape = tuple(getattr(value, "shape", ()))
        if len(shape) == 2:
            return int(shape[1])
        if len(shape) > 2:  # a convolution first: an image model
            return None
    return None


def _check_features_width(model: OpenModel, world) -> None:
    """A features model reads a vector whose length depends on the race it was trained in: boxes and bot cars add
    the nearest objects ahead (`FEATURE_OBJECTS` (x, y) pairs), a time trial and a head-to-model race do not.
    Racing it in the other kind is refused with that cause and the race that fits, before the network is built."""
    from racerlab.sim.objects import FEATURE_OBJECTS

    if getattr(world.observation, "name", None) != "features":
        return
    policy = model.state.agent.get("policy")
    saved = _input_width(policy) if isinstance(policy, dict) else None
    now = int(world.observation.space.shape[0])
    if saved is None or saved == now or abs(saved - now) != 2 * FEATURE_OBJECTS:
        return  # the same width, or another mismatch the loader names
    trained = model.config.race.type
    had, has = ("had", "has none (a time trial or a head-to-model race)") if saved > now else ("had no", "has some")
    raise RacerlabError(
        f"{model.path}: this features model reads {saved} numbers and this race "
        f"gives it {now}: the features vector ends with the nearest {FEATURE_OBJECTS} boxes or bot cars ahead when a "
        f"race has them; its training race ({trained}, {model.folder.config_path}) {had} boxes or bot cars and this "
        f"race {has}; race it in the kind of race it trained in (`--race-type {trained}`) or train a model for "
        "this kind of race")


def race_config(model: OpenModel, race=None, where: str = "racerlab evaluate"):
    """The race an evaluation drives: the model's training.toml [race]; a `RaceConfig` replaces it, a dict of
    [race] keys overrides those keys of it (`where` names the source in a bad key's one-line error)."""
    if isinstance(race, RaceConfig):
        return race
    base = model.config.race
    if not race:
        return base
    table = race_table(base)
    if race.get("type") == "head_to_model":  # the racing cars alone: the model's own boxes and bots stay home
        table.update(number_of_obstacles=0, object_positions=[], number_of_bot_cars=0)
    return RaceConfig.from_mapping({**table, **race}, where=where)


def car_config(model: OpenModel, car=None):
    """The car an evaluation drives: `car` (a `CarParams`, a simulator name or a `[car]` dict, see
    `racerlab.sim.car_for`) or, by default, the model's training.toml [car], without step jitter (an evaluation
    repeats exactly unless the table sets `step_jitter`)."""
    from racerlab.sim import car_for

    if car is None:
        return model.config.car.params(model.metadata.version, training=False)
    return car_for(car, model.metadata)


def make_world(model: OpenModel, track, rules: RaceRules, seed: int = RACE_SEED, reward=None, race=None,
               randomise=None, car=None):
    """The race world. The model folder's reward_function.py is never imported (racing someone's model must
    not run their code): the reward column is 0, as AWS's evaluation logs it, unless `reward` (a callable or
    a path the user chose) is given. `race` (a RaceConfig, or [race] keys over the model's): see `race_config`.
    `randomise`: domain randomisation or the physical car's speed mapping (`RandomiseSettings` or its dict).
    `car`: see `car_config`."""
    from racerlab.sim import StartRules, World

    # evaluation places the car itself (`reset(start_ndist=0)`), so the round robin is never used
    start = StartRules(reverse=rules.reverse)
    return World(track, 1, model.metadata, reward, model.observation, start=start,
                 max_episode_steps=rules.max_episode_steps, seed=seed, race=race_config(model, race),
                 randomise=randomise, car=car_config(model, car), look=model.look)


def run_pair(models, track, rules: RaceRules, *, video: bool = False, on_lap=None, device: str = "cpu",
             where: str = "racerlab evaluate", car=None, seed: int = RACE_SEED):
    """Two loaded models (or one model twice) in one head-to-model world, a car each, under `rules`: the
    worlds (one per car, sharing the simulator) and each car's `EvalRun`."""
    from racerlab.sim import StartRules, World

    first = World(track, 2, models[0].metadata, None, models[0].observation, start=StartRules(reverse=rules.reverse),
                  max_episode_steps=rules.max_episode_steps, seed=seed,
                  race=RaceConfig(type="head_to_model", where=where), car=car_config(models[0], car),
                  look=models[0].look)
    worlds = [first, World(None, 2, models[1].metadata, None, models[1].observation, sim=first.sim,
                           look=models[1].look)]
    policies = [make_policy(m, w, device) for m, w in zip(models, worlds, strict=True)]
    image_of = None
    if video:
        from racerlab.evaluate.video import camera_image

        image_of = camera_image
    runs = run_head_to_model(worlds, policies, rules, keep_frames=video, image_of=image_of, on_lap=on_lap)
    return worlds, runs


# ---- evaluate -------------------------------------------------------------------------------------


def evaluate(model_dir, track=None, trials: int = RaceRules.trials, continuous: bool = RaceRules.continuous,
             off_track_penalty: float = RaceRules.off_track_penalty,
             collision_penalty: float = RaceRules.collision_penalty, max_resets: int = RaceRules.max_resets,
             checkpoint: str | int = "best",
             reverse: bool = False, video: bool = False, *, rules: RaceRules | None = None,
             ranking_laps: int = DEFAULT_RANKING_LAPS, write: bool = True, device: str = "cpu",
             progress: bool = False, on_lap=None, reward=None, race=None, randomise=None, car=None) -> EvaluationResult:
    """Evaluate the model in `model_dir` under race rules (DRfC defaults) and write its evaluation folder.

    `track` is a name or path (default: the model's first training track); `checkpoint` is best, last
    or an iteration number. `rules` replaces the individual rule arguments. With `video` an MP4 of
    the run is written too (`progress` shows rendering progress on stderr). `write=False` keeps
    everything in memory. `on_lap(lap)` is called as each lap ends. The folder's reward_function.py is not
    run: the reward column is 0 (as AWS logs evaluations) unless `reward` (a callable or a file) is given.
    `race` (a RaceConfig, or a dict of [race] keys over the model's training.toml [race]): boxes crash the car,
    which restarts 1 m behind the box; a bot car crash holds the car where it is. `randomise`
    (`RandomiseSettings` or its dict) drives the car under domain randomisation, or with the physical car's
    speed mapping. `car` (see `car_config`; default the model's training.toml [car]) is the simulator's car.
    """
    rules = rules or RaceRules(trials=trials, continuous=continuous, off_track_penalty=off_track_penalty,
                               collision_penalty=collision_penalty, max_resets=max_resets, reverse=reverse)
    model = ModelFolder(model_dir).open(checkpoint)
    track_obj = resolve_track(model.folder, track)
    return evaluate_loaded(model, track_obj, rules, ranking_laps=ranking_laps, video=video, write=write, device=device,
                           progress=progress, on_lap=on_lap, reward=reward, race=race, randomise=randomise, car=car)


def evaluate_loaded(model: OpenModel, track, rules: RaceRules, *, ranking_laps: int = DEFAULT_RANKING_LAPS,
                    video: bool = False, write: bool = True, device: str = "cpu", progress: bool = False, on_lap=None,
                    reward=None, race=None, randomise=None, car=None, seed: int = RACE_SEED,
                    out_dir: Path | None = None, video_width: int = VIDEO_WIDTH_PX,
                    video_title: str | None = None, video_every: int = 1) -> EvaluationResult:
    """`evaluate` of a model already open (`ModelFolder.open`, or a race server's stored model) on a `Track`: the
    same race, result and files. `seed` seeds the world (boxes and bots drawn at random, randomisation);
    `out_dir` (created) receives the evaluation's files instead of a new `<model>/evaluation-<stamp>/`;
    `video_width` is the track picture's width in the video (pixels), `video_title` its title (default: the
    model's folder name and the track), `video_every` k draws every k-th step (`video.render_video`)."""
    if race_config(model, race).head_to_model:  # the model races a copy of itself; car 0's run is its result
        if randomise is not None or reward is not None:
            raise RacerlabError("racerlab evaluate: a head_to_model evaluation races the model against itself "
                                "without randomise or reward; drop those options or evaluate another race type")
        worlds, runs = run_pair([model, model], track, rules, video=video, device=device, car=car, seed=seed,
                                on_lap=(lambda k, lap: on_lap(lap) if k == 0 else None) if on_lap else None)
        world, run = worlds[0], runs[0]
    else:
        world = make_world(model, track, rules, seed=seed, reward=reward, race=race, randomise=randomise, car=car)
        policy = make_policy(model, world, device)
        image_of = None
        if video:
            from racerlab.evaluate.video import camera_image

            image_of = camera_image
        run = run_evaluation(world, policy, rules, keep_frames=video, image_of=image_of, on_lap=on_lap)
    result = EvaluationResult(model.name, model.folder.path, model.checkpoint.name, track.name,
                              rules, run.laps, race_result(run.laps, ranking_laps), steps=run.rows,
                              wall_seconds=run.wall_seconds, run=run, race=race_table(world.sim.race),
                              randomise=world.randomise.changed() if world.randomise else None,
                              car=world.sim.car_params.name)
    if write:
        _write(result, world, video, progress, out_dir, (video_width, video_title, video_every))
    return result


def race_table(race: RaceConfig) -> dict:
    """A RaceConfig as its [race] table (DRfC's names)."""
    return race.table()


def _write(result: EvaluationResult, world, video: bool, progress: bool, out: Path | None = None,
           look: tuple = (VIDEO_WIDTH_PX, None, 1)) -> None:
    """The evaluation's files in `out` (default: a new evaluation folder of the model); `look` is the video's
    (track width in pixels, title or None, every k-th step)."""
    video_width, video_title, video_every = look
    if out is None:
        out = logs.new_evaluation_dir(result.model_dir)
    else:
        out.mkdir(parents=True, exist_ok=True)
    result.out_dir = out
    run = result.run
    result.files["simtrace"] = logs.write_simtrace(logs.eval_simtrace_path(out), run.trace)
    metrics = logs.EvalMetrics(logs.eval_metrics_path(out))
    metrics.add([lap.eval_metrics_entry() for lap in result.laps])
    result.files["eval_metrics"] = metrics.save()
    if run.layouts:  # where the boxes / bots stood in each episode (random layouts change at every reset)
        result.files["layouts"] = logs.atomic_write_json(logs.eval_layouts_path(out), run.layouts)
    # the summary first: a video that fails (or is interrupted) leaves a complete evaluation
    _write_summary(result)
    if video:
        from racerlab.evaluate.video import render_video

        sim = world.sim
        track = sim.track_reversed if result.rules.reverse else sim.track
        t0 = time.perf_counter()
        title = video_title if video_title is not None else f"{result.model} on {result.track}"
        result.files["video"] = render_video(out / VIDEO_NAME, track, run, title=title,
                                             max_speed=_top_speed(world.metadata), progress=progress,
                                             width_px=video_width, frame_every=video_every)
        result.wall_seconds += time.perf_counter() - t0
        _write_summary(result)


def _write_summary(result: EvaluationResult) -> None:
    result.files["summary"] = result.out_dir / SUMMARY_NAME
    logs.atomic_write_json(result.files["summary"], logs.finite_json(result.summary()), indent=2)


def _top_speed(metadata) -> float:
    """The video's speed-bar scale: the action space's top speed, at least HUD_MIN_TOP_SPEED, at most MAX_SPEED."""
    return min(max(metadata.actions.top_speed, HUD_MIN_TOP_SPEED), MAX_SPEED)


