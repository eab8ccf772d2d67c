"""`write_report(path)`: one self-contained HTML file (figures embedded as base64 PNG, no external files or
scripts) that analyses a training or evaluation log: summary, training progress, lap times, tables of the
best episodes, track heatmaps, episode paths, action usage and speed/steering per waypoint, and for a
model folder one section per evaluation and race it drove (laps, lap times, off-tracks, best lap, video).

Iterations are numbered as the training console and the checkpoint names count them: iteration 1 is the
first, whose steps are in `training-simtrace/0-iteration.csv` (the simtrace files count from 0).

The track comes from `track=` (a name, path or `Track`), else from a racerlab model folder's
training.toml, else from the bundled and user tracks whose length equals the log's `track_len`. Without
one the track figures are left out and the report says why.
"""

from __future__ import annotations

import base64
import html
import io
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from racerlab.analysis import plots as P
from racerlab.analysis.episodes import episode_summary, iteration_summary, run_metrics, step_kinematics
from racerlab.errors import RacerlabError
from racerlab.logs import BEST_LAP_MEANING, BEST_LAP_NAME, best_eval_lap, eval_layouts_path
from racerlab.logs.atomic import atomic_write_text
from racerlab.logs.files import read_bytes, special
from racerlab.model import ModelFolder, resolve_track
from racerlab.spec import STEP_S, RaceConfig
from racerlab.track import Track

PNG_DPI = 90
TABLE_ROWS = 10


# ---------------------------------------------------------------------------------------------------------
# the files beside the logs: read through `logs.files`, like the logs (a pipe or a device there is left out)

SIDE_FILE_BYTES = 64 << 20  # a summary.json or layouts.json is kilobytes


def side_json(path: Path):
    """The JSON of a file beside the logs (summary.json, layouts.json), or None when it is missing, no regular
    file, too long or damaged: the report goes on without it."""
    try:
        return json.loads(read_bytes(path, limit=SIDE_FILE_BYTES))
    except ValueError:  # LogFileError included
        return None


def readable_config(folder) -> bool:
    """Whether the training.toml of `folder` (when there is one) can be read: not a pipe or a device, which would
    block or flood the read."""
    return special(Path(folder) / "training.toml") is None


# ---------------------------------------------------------------------------------------------------------
# finding the track


def log_track(path, df: pd.DataFrame, track=None) -> tuple[Track | None, str]:
    """The track to draw `df` (logged in `path`) on, and a sentence saying where it came from (or why there is
    none)."""
    from racerlab import track as tracks

    if isinstance(track, Track):
        return track, "given"
    if track:
        return tracks.load(track), "given with --track"
    try:
        names = ModelFolder(path).tracks(default=False) if readable_config(path) else ()
    except RacerlabError:
        names = ()
    if names:
        try:
            return resolve_track(path, default=False), "from the model folder's training.toml"
        except RacerlabError as exc:
            return None, f"the model folder's track cannot be loaded ({exc}); pass --track"
    evaluated = _evaluation_track(Path(path))
    if evaluated is not None:
        return evaluated, "named in the evaluation's summary.json"
    found, same = _tracks_of_length(df)
    if len(found) == 1:
        alias = f"; {', '.join(same)} {'is' if len(same) == 1 else 'are'} the same geometry" if same else ""
        return found[0], f"the only known track {_track_len(df):.2f} m long (the log's track_len{alias})"
    if found:
        names = ", ".join(t.name for t in found)
        return None, f"several known tracks are {_track_len(df):.2f} m long ({names}); pass --track"
    return None, "the log does not name its track; pass --track NAME_OR_FILE for the track figures"


def _evaluation_track(folder: Path) -> Track | None:
    """The track an evaluation folder's summary.json names: a known track of that name, else the model folder's
    (the folder above) when its training track has that name."""
    from racerlab import track as tracks

    try:
        name = side_json(folder / "summary.json")["track"]
    except (KeyError, TypeError):
        return None
    try:
        return tracks.load(name)
    except RacerlabError:
        pass
    try:
        trk = resolve_track(folder.parent, default=False) if readable_config(folder.parent) else None
    except RacerlabError:
        return None
    if trk is None:
        return None
    return trk if trk.name == name else None


def _track_len(df: pd.DataFrame) -> float:
    return float(df["track_len"].median()) if len(df) else float("nan")


def _tracks_of_length(df: pd.DataFrame) -> tuple[list[Track], list[str]]:
    """Known tracks as long as the log's track_len, one per distinct geometry (AWS ships some route files
    under several names, e.g. reinvent_base = reinvent_carpet = reinvent_concrete = reinvent_wood: the
    first name in sorted order stands for them), and the names of the identical files left out."""
    from racerlab import track as tracks
    from racerlab.track.registry import catalogue

    target = _track_len(df)
    out: dict[bytes, Track] = {}
    same = []
    for name in sorted(catalogue()):
        try:
            t = tracks.load(name)
        except RacerlabError:
            continue
        if abs(round(t.length, 2) - target) <= 0.011:
            key = t.as_array().tobytes()
            if key in out:
                same.append(name)
            else:
                out[key] = t
    return list(out.values()), same


def rows_on_track(df: pd.DataFrame, track: Track) -> pd.DataFrame:
    """Rows logged on `track` (by their track_len), for logs of a training over several tracks."""
    tl = df["track_len"].to_numpy()
    same = np.abs(tl - round(track.length, 2)) <= 0.011
    return df if same.all() or not same.any() else df[same]


# ---------------------------------------------------------------------------------------------------------
# HTML pieces


def png_data_uri(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=PNG_DPI)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


@dataclass
class _Doc:
    title: str
    parts: list[str] = field(default_factory=list)
    say: object = None  # progress(text) while the report is made, or None

    def step(self, text: str) -> None:
        if self.say is not None:
            self.say(text)

    def h2(self, text: str, anchor: str) -> None:
        self.parts.append(f'<h2 id="{anchor}">{html.escape(text)}</h2>')

    def p(self, text: str, cls: str = "") -> None:
        c = f' class="{cls}"' if cls else ""
        self.parts.append(f"<p{c}>{html.escape(text)}</p>")

    def figure(self, fig, caption: str) -> None:
        self.parts.append(f'<figure><img alt="{html.escape(caption)}" src="{png_data_uri(fig)}">'
                          f"<figcaption>{html.escape(caption)}</figcaption></figure>")

    def table(self, df: pd.DataFrame, caption: str = "") -> None:
        if caption:
            self.parts.append(f"<h3>{html.escape(caption)}</h3>")
        df = df.rename(columns=_HEADERS)
        df.index.name = _HEADERS.get(df.index.name, df.index.name)
        body = df.to_html(classes="t", float_format=lambda v: f"{v:.4g}", na_rep="", border=0)
        self.parts.append(f'<div class="tw">{body}</div>')  # a wide table scrolls inside the page

    def render(self, toc: list[tuple[str, str]]) -> str:
        nav = " · ".join(f'<a href="#{a}">{html.escape(t)}</a>' for a, t in toc)
        return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(self.title)}</title>"
                f"<style>{_CSS}</style></head><body><h1>{html.escape(self.title)}</h1><nav>{nav}</nav>"
                + "\n".join(self.parts) + "</body></html>")


_CSS = """body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1300px;color:#222;padding:0 1em}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-top:.6em}h3{font-size:1em;margin-bottom:.3em}
nav{margin-bottom:1em;line-height:1.8}figure{margin:1em 0}img{max-width:100%;border:1px solid #eee}
figcaption{color:#555;font-size:.9em}table.t{border-collapse:collapse;font-size:.85em;margin:.5em 0}
table.t td,table.t th{padding:.2em .6em;border-bottom:1px solid #eee;text-align:right}
.note{color:#8a5300;background:#fff6e5;padding:.4em .8em}.kv td{padding:.1em 1em .1em 0}
.tw{max-width:100%;overflow-x:auto}table.t th{white-space:normal;max-width:7em;vertical-align:bottom}"""

# short table headers, so that the tables fit the page
_HEADERS = {"unique_episode": "episode", "start_waypoint": "start wp", "lap_time": "lap time (s)",
            "time": "time (s)", "distance": "distance (m)", "true_speed": "speed (m/s)", "speed": "cmd speed",
            "reward_mean": "reward mean", "reward_std": "reward std", "progress_mean": "progress %",
            "completion_rate": "lap share", "lap_time_min": "best lap (s)", "lap_time_mean": "mean lap (s)",
            "train_completion": "train progress %", "eval_completion": "eval progress %",
            "eval_lap_time_min": "best eval lap (s)", "approx_kl": "approx KL"}


# ---------------------------------------------------------------------------------------------------------
# the report


def write_report(path, out=None, track=None, *, kind: str = "auto", progress=None) -> Path:
    """Analyse the log(s) at `path` (anything `racerlab.analysis.load` reads) into one HTML file `out`
    (default: `<folder>/report.html`, or `<file>-report.html` beside a file); returns its path. `progress(text)`,
    when given, hears what is being done (loading, each section), with the seconds so far."""
    from racerlab.analysis.load import load

    t0 = time.perf_counter()

    def say(text):
        if progress is not None:
            progress(f"{text} ({time.perf_counter() - t0:.0f} s)")

    path = Path(path)
    say(f"reading the logs in {path}")
    df = load(path, kind)
    if len(df) == 0:
        raise RacerlabError(f"{path}: the logs hold no steps to analyse")
    say(f"{len(df):,} steps read")
    out = Path(out) if out else report_path(path)
    trk, track_note = log_track(path, df, track)
    doc = _Doc(f"racerlab report: {path.name or path}", say=say)
    toc = _build(doc, path, df, trk, track_note, out)
    return atomic_write_text(out, doc.render(toc))


def count_iterations_from_one(eps: pd.DataFrame | None = None, its: pd.DataFrame | None = None) -> None:
    """Renumber (in place) the 0-based iterations of the simtrace files as the training console and the
    checkpoint names count them: iteration 1 is the one that wrote 0-iteration.csv. Every table and
    figure shown to a user uses this numbering."""
    if eps is not None:
        eps["iteration"] += 1
    if its is not None:
        its.index = its.index + 1


REPORT_NAME = "report.html"  # a folder's report, as `racerlab report` and the console write it


def report_path(path: Path) -> Path:
    """Where the report of the logs at `path` goes unless told: `report.html` in a folder, `<name>-report.html`
    beside a file (its archive or log suffix dropped). The CLI and the console both name reports this way."""
    if path.is_dir():
        return path / REPORT_NAME
    name = path.name
    for suffix in (".tar.gz", ".tgz", ".tar", ".gz", ".csv", ".log"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
            break
    return path.with_name(f"{name}-report.html")


def _build(doc: _Doc, path: Path, df: pd.DataFrame, trk: Track | None, track_note: str,
           out: Path) -> list[tuple[str, str]]:
    doc.step("episodes and iterations")
    kin = step_kinematics(df)
    eps = episode_summary(df, kin)
    training = df.attrs.get("kind", "training") == "training"
    tm, jsonl = run_metrics(path) if training else (None, [])
    its = iteration_summary(eps, tm, jsonl)
    count_iterations_from_one(eps, its)
    toc = [("summary", "Summary")]
    _summary(doc, path, df, eps, trk, track_note, jsonl)
    if training:
        doc.step("training progress")
        toc.append(("progress", "Training progress"))
        doc.h2("Training progress", "progress")
        doc.figure(P.training_progress(its), "Per iteration (numbered as the console and the checkpoint names: "
                                             "iteration 1 is 0-iteration.csv): simtrace episodes, TrainingMetrics.json "
                                             "(training and in-training evaluation) and metrics.jsonl (entropy, KL)")
        doc.figure(P.learner_health(its, fast_lap_share(eps, its)),
                   "Why a run stops getting faster (docs/learner.md): the exploring actions' spread, the value "
                   "net's fit, how often training laps are as fast as the best evaluation lap, and that lap in "
                   "1/15 s steps")
        doc.table(_iteration_table(its), "Per iteration" if len(its) <= 40 else
                  f"Per iteration: the first 10 and the last 30 of {len(its)}")
    evaluations = _evaluation_summaries(path)
    if evaluations:
        toc.append(("evaluations", "Evaluations and races"))
        _evaluations(doc, evaluations, out)
    toc.append(("laps", "Lap times and episodes"))
    doc.step("lap times")
    _laps(doc, eps)
    if trk is not None:
        doc.step("heatmaps and paths on the track")
        toc += [("track", "On the track"), ("paths", "Episode paths")]
        _track_views(doc, rows_on_track(df, trk).assign(true_speed=kin["true_speed"], slide=kin["slide"]),
                     trk, eps)
    race, race_note = log_race(path)
    crashes = int((df["episode_status"].astype(str) == "crashed").sum()) if "episode_status" in df else 0
    if trk is not None and (crashes or (race is not None and race.has_objects)):
        toc.append(("objects", "Objects and crashes"))
        _objects(doc, rows_on_track(df, trk), trk, race, race_note, log_layouts(path))
    toc += [("actions", "Actions"), ("waypoints", "Per waypoint")]
    doc.step("actions and the per-waypoint profile")
    doc.h2("Action space usage", "actions")
    doc.figure(P.action_usage(df.assign(iteration=df["iteration"] + 1)),
               "Steps per action (continuous spaces: binned steering x speed)")
    doc.h2("Speed and steering per waypoint", "waypoints")
    doc.figure(P.waypoint_profile(rows_on_track(df, trk) if trk is not None else df, trk),
               "Commanded and true speed, and steering, averaged per waypoint (grey: turns tighter than 2 m radius)")
    return toc


def fast_lap_share(eps: pd.DataFrame, its: pd.DataFrame) -> pd.Series | None:
    """Per iteration, the share of training episodes whose lap was within one 1/15 s step of the run's best
    evaluation lap: how often exploring still drives the fast line. None without an evaluation lap."""
    if "eval_best_lap" not in its or not its["eval_best_lap"].notna().any() or "lap_time" not in eps:
        return None
    near = eps["lap_time"] <= its["eval_best_lap"].min() + 1.5 * STEP_S
    return near.groupby(eps["iteration"]).mean()


def _lap_items(df: pd.DataFrame, eps: pd.DataFrame, jsonl: list[dict]) -> dict[str, str]:
    """The summary's laps, each named for the episodes it counts: a training log's fastest training episode
    (exploring actions) apart from its best eval lap (greedy, `racerlab.logs.BEST_LAP_MEANING`, the lap the
    console and the training's own lines show); an evaluation's best lap is its fastest lap."""
    laps = eps["lap_time"].dropna()
    fastest = f"{laps.min():.3f} s (episode {int(laps.idxmin())})" if len(laps) else "none yet"
    if df.attrs.get("kind", "training") != "training":
        return {"best lap": fastest}
    best = best_eval_lap(jsonl)
    if best is not None:
        shown = f"{best[0]:.3f} s" + (f" (iteration {best[1]})" if best[1] is not None else "")
    else:
        shown = "none yet" if jsonl else "not in these logs (racerlab's metrics.jsonl holds it)"
    return {BEST_LAP_NAME: shown, "fastest training-episode lap": fastest}


def _summary(doc: _Doc, path: Path, df: pd.DataFrame, eps: pd.DataFrame, trk: Track | None, note: str,
             jsonl: list[dict] | None = None) -> None:
    from racerlab import __version__

    doc.h2("Summary", "summary")
    items = {
        "source": str(path.resolve()),
        "kind": df.attrs.get("kind", ""),
        "steps": f"{len(df):,}",
        "episodes": f"{len(eps):,}",
        "iterations": f"{df['iteration'].nunique():,}",
        "complete laps": f"{int(eps['complete'].sum()):,} ({100 * eps['complete'].mean():.1f} %)",
        **_lap_items(df, eps, jsonl or []),
        "mean progress": f"{eps['progress'].mean():.1f} %",
        "outcomes": ", ".join(f"{k} {v}" for k, v in eps["outcome"].value_counts().items()),
        "crashes": f"{int((df['episode_status'].astype(str) == 'crashed').sum()):,} steps judged crashed"
        if "episode_status" in df else "not logged",
        "track": f"{trk.name} ({trk.length:.2f} m), {note}" if trk is not None else f"none: {note}",
        "made": f"{time.strftime('%Y-%m-%d %H:%M:%S')} by racerlab {__version__}",
    }
    rows = "".join(f"<tr><td><b>{html.escape(k)}</b></td><td>{html.escape(v)}</td></tr>" for k, v in items.items())
    doc.parts.append(f'<table class="kv">{rows}</table>')
    if BEST_LAP_NAME in items:
        doc.p(f"{BEST_LAP_NAME}: {BEST_LAP_MEANING}; a training episode's lap is driven with exploring actions.")
    if df.attrs.get("converted_to_degrees"):
        doc.p(f"Logs in radians were converted to degrees: {', '.join(df.attrs['converted_to_degrees'])}", "note")
    if trk is None:
        doc.p(f"Track figures left out: {note}.", "note")


def log_race(path) -> tuple[RaceConfig | None, str]:
    """The race a log was driven in, and where that came from: an evaluation folder's summary.json "race", else
    the [race] of the model folder's training.toml (the folder itself or one of the two above it)."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    summary = folder / "summary.json"
    table = (side_json(summary) or {}).get("race") if summary.is_file() else None
    if isinstance(table, dict) and table:
        try:
            return RaceConfig.from_mapping(table, where=str(summary)), "from the evaluation's summary.json"
        except RacerlabError:
            pass
    for candidate in (folder, folder.parent, folder.parent.parent):
        if not readable_config(candidate):
            continue
        try:
            return ModelFolder(candidate).config().race, "from the model folder's training.toml [race]"
        except (RacerlabError, OSError):
            continue
    return None, "no race settings found beside the log"


def log_layouts(path) -> list[dict] | None:
    """The layouts an evaluation's episodes had (`layouts.json` beside the log, written by `racerlab evaluate`
    for races with boxes or bot cars), each as `plots.crash_map` takes it plus "episodes" (the simtrace episode
    numbers it stood for); None when there is no such file (training logs, older evaluations)."""
    path = Path(path)
    f = eval_layouts_path(path if path.is_dir() else path.parent)
    if not f.is_file():
        return None
    try:
        rec = side_json(f)
        return [{"kind": rec["kind"], "size": tuple(rec["size"]), "xy": np.asarray(lay["xy"], dtype=float),
                 "yaw": np.asarray(lay["yaw"], dtype=float), "lane": np.asarray(lay["lane"]),
                 "episodes": [int(e) for e in lay["episodes"]]} for lay in rec["layouts"]]
    except (OSError, ValueError, KeyError, TypeError):
        return None  # damaged: the crash map falls back to the race settings


def _same_layout(layouts: list[dict]) -> bool:
    return all(np.array_equal(lay["xy"], layouts[0]["xy"]) for lay in layouts[1:])


def _objects(doc: _Doc, df: pd.DataFrame, trk: Track, race: RaceConfig | None, note: str,
             layouts: list[dict] | None = None) -> None:
    from racerlab.sim.objects import race_layout

    doc.h2("Objects and crashes", "objects")
    if layouts and not _same_layout(layouts):  # random layouts: one panel per episode layout, as it was driven
        doc.figure(P.crash_maps(df, trk, layouts),
                   f"Every crashed step (red cross at the car's model point) with the {_object_words(layouts[0])} "
                   f"of the episodes it happened in (layouts.json); race: {race.type if race else 'unknown'} "
                   f"({note})")
        _most_crashes(doc, df)
        return
    layout = layouts[0] if layouts else race_layout(race, trk) if race is not None else None
    if layout is not None:
        why = ""
    elif race is None:
        why = note
    elif race.head_to_model:
        why = "head to model: the other car moves, it is not drawn"
    elif race.has_objects:
        why = "random layout, re-drawn every episode: objects not drawn"
    else:
        why = ""
    what = _object_words(layout)
    doc.figure(P.crash_map(df, trk, layout, note=why),
               f"Every crashed step (red cross at the car's model point){' and the ' + what if what else ''}; "
               f"race: {race.type if race else 'unknown'} ({note})")
    _most_crashes(doc, df)


def _object_words(layout: dict | None) -> str:
    return {"box": "boxes", "bot": "bot cars at their start (arrow: driving direction)"}.get(
        layout["kind"] if layout else "", "")


def _most_crashes(doc: _Doc, df: pd.DataFrame) -> None:
    status = df["episode_status"].astype(str)
    per = df.assign(crash=status == "crashed").groupby("unique_episode")["crash"].sum()
    if per.any():
        doc.table(per[per > 0].sort_values(ascending=False).head(TABLE_ROWS).to_frame("crashes"),
                  "Episodes with the most crashes")


def _iteration_table(its: pd.DataFrame) -> pd.DataFrame:
    cols = [c for c in ("episodes", "reward_mean", "reward_std", "progress_mean", "completion_rate",
                        "lap_time_min", "lap_time_mean", "train_completion", "eval_completion", "eval_lap_time_min",
                        "entropy", "approx_kl") if c in its and its[c].notna().any()]
    t = its[cols]
    if len(t) <= 40:
        return t
    head, tail = t.head(10), t.tail(30)
    gap = pd.DataFrame([[None] * len(cols)], columns=cols,
                       index=[f"{head.index[-1] + 1}–{tail.index[0] - 1}: not shown"])
    return pd.concat([head, gap, tail])


_EPISODE_COLUMNS = ["iteration", "outcome", "start_waypoint", "steps", "time", "progress", "reward", "lap_time",
                    "distance", "true_speed", "speed"]


def _laps(doc: _Doc, eps: pd.DataFrame) -> None:
    doc.h2("Lap times and episodes", "laps")
    doc.figure(P.lap_time_distribution(eps), "Lap times of complete laps")
    cols = [c for c in _EPISODE_COLUMNS if c in eps]
    laps = eps[eps["complete"]]
    tables = []
    if len(laps):
        tables += [(laps.nsmallest(TABLE_ROWS, "lap_time"), "Fastest laps"),
                    (laps.nlargest(TABLE_ROWS, "reward"), "Best rewarded laps")]
    tables.append((eps.sort_values(["progress", "reward"], ascending=False).head(TABLE_ROWS), "Most progress"))
    shown: dict[frozenset, str] = {}
    for rows, caption in tables:
        key = frozenset(rows.index)
        if key in shown:  # the same episodes again: say so instead of a second copy
            doc.p(f"{caption}: the same episodes as “{shown[key]}” above.")
            continue
        shown[key] = caption
        doc.table(rows[cols], caption)
    out = eps.groupby("start_waypoint").agg(episodes=("progress", "size"), progress=("progress", "mean"),
                                            laps=("complete", "sum"))
    if 1 < len(out) <= 40:
        doc.table(out.T, "By start waypoint (mean progress, complete laps)")


def _track_views(doc: _Doc, df: pd.DataFrame, trk: Track, eps: pd.DataFrame) -> None:
    doc.h2("On the track", "track")
    run = df[df["episode_status"].astype(str) != "prepare"] if "episode_status" in df else df
    doc.figure(P.track_heatmap(run, trk, "reward", "mean", 0.1), "Mean reward per 10 cm cell (all steps)")
    doc.figure(P.track_heatmap(run, trk, "true_speed", "mean", 0.1, cmap="plasma"),
               "Mean true speed (m/s, from positions) per 10 cm cell")
    doc.figure(P.track_heatmap(run, trk, "reward", "count", 0.1, cmap="magma"),
               "Steps per 10 cm cell: where cars go")
    ends = df.groupby("unique_episode").tail(1)
    ends = ends[ends["episode_status"].astype(str).isin(["off_track", "crashed", "reversed", "immobilized"])]
    if len(ends):
        doc.figure(P.track_heatmap(ends, trk, "reward", "count", 0.25, cmap="Reds", rows="episode ends",
                                   title=f"where {len(ends):,} episodes ended off track, crashed, reversed or "
                                         "immobilized (25 cm cells)"),
                   f"Where episodes ended off track, crashed, reversed or immobilized: episodes ending in each "
                   f"25 cm cell ({len(ends)} episodes)")
    doc.h2("Episode paths", "paths")
    for ids, what in _chosen_episodes(eps):
        doc.figure(P.episode_paths(df, trk, ids, "speed", title=f"{what}: commanded speed"),
                   f"{what} (episodes {', '.join(map(str, ids))}), coloured by commanded speed")
    best = _chosen_episodes(eps)[0][0][:1]
    doc.figure(P.episode_paths(df, trk, best, "action", title=f"episode {best[0]}: actions"),
               f"Episode {best[0]} coloured by action")
    doc.figure(P.episode_paths(df, trk, best, "true_speed", title=f"episode {best[0]}: true speed"),
               f"Episode {best[0]} coloured by true speed (m/s, from positions)")


# ---------------------------------------------------------------------------------------------------------
# evaluations and races


def _evaluation_summaries(path: Path) -> list[tuple[Path, dict]]:
    """The `summary.json` of every `evaluation-<stamp>/` of a model folder (evaluate and race write one each)."""
    if not path.is_dir():
        return []
    out = []
    for f in sorted(path.glob("evaluation-*/summary.json")):
        doc = side_json(f)
        if isinstance(doc, dict):  # None: still being written, damaged or no file: its simtrace is still analysed
            out.append((f.parent, doc))
    return out


def _evaluations(doc: _Doc, evaluations: list[tuple[Path, dict]], out: Path) -> None:
    doc.h2("Evaluations and races", "evaluations")
    doc.p("Every evaluation of this model (`racerlab evaluate`, and each model's run in `racerlab race`), "
          "newest last; times include the off-track penalties, as AWS times them.")
    for folder, s in evaluations:
        rules = s.get("rules", {})
        r = s.get("result", {})
        mode = "continuous" if rules.get("continuous", True) else "separate"
        trials = rules.get("trials", "?")
        doc.parts.append(f"<h3>{html.escape(folder.name)}: checkpoint {html.escape(str(s.get('checkpoint')))} on "
                         f"{html.escape(str(s.get('track')))}, {trials} trial{'' if trials == 1 else 's'} "
                         f"({mode} laps), "
                         f"off-track penalty {rules.get('off_track_penalty', '?')} s</h3>")
        laps = pd.DataFrame([{"lap": lap["trial"], "time (s)": lap["elapsed"], "status": lap["status"],
                              "progress %": lap["progress"], "off-track": lap["off_track"], "resets": lap["resets"]}
                             for lap in s.get("laps", [])])
        if len(laps):
            doc.table(laps.set_index("lap"))
        best = r.get("best_lap")
        doc.p(f"result: {r.get('text', '?')}; best lap {'-' if best is None else f'{best:.3f} s'}; "
              f"{r.get('off_track', 0)} off-track; total {r.get('total_time', 0):.3f} s")
        video = s.get("files", {}).get("video")
        if video:
            rel = os.path.relpath(folder / video, out.parent)
            doc.parts.append(f'<p><a href="{html.escape(rel)}">video: {html.escape(rel)}</a></p>')


def _chosen_episodes(eps: pd.DataFrame) -> list[tuple[list[int], str]]:
    laps = eps[eps["complete"]]
    out = []
    if len(laps):
        out.append((laps.nsmallest(3, "lap_time").index.tolist(), "Fastest laps"))
    last = eps[eps["iteration"] == eps["iteration"].max()]
    out.append((last.sort_values(["progress", "reward"], ascending=False).head(3).index.tolist(),
                "Most progress in the last iteration"))
    return out


__all__ = ["count_iterations_from_one", "log_race", "log_track", "png_data_uri", "rows_on_track", "write_report"]
