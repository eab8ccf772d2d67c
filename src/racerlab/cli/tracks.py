"""`racerlab tracks list|show|generate|fetch|import`: what tracks there are, a picture of one, a new random one,
the AWS tracks downloaded or imported by name."""

from __future__ import annotations

import sys
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("tracks", help="list, draw and generate tracks",
                       description="List the bundled and user tracks, draw one, or generate a new one.")
    tsub = p.add_subparsers(dest="tracks_command", metavar="ACTION")
    tsub.required = True

    ls = tsub.add_parser("list", help="name, source, length, width and turns of every known track")
    ls.set_defaults(func=run_list)

    show = tsub.add_parser("show", help="draw a track to a PNG and print its size",
                           description="Write a picture of a track (borders, centre line, start, direction, "
                                       "waypoint numbers) and print its length, width, turns and direction.")
    show.add_argument("track", metavar="NAME|PATH", nargs="?", default=None,
                      help="a track name (see `racerlab tracks list`) or a .npy file (default: the default track)")
    show.add_argument("--out", type=Path, default=None,
                      help="PNG file to write (default racerlab-out/tracks/<name>.png)")
    show.add_argument("--reverse", action="store_true", help="the track driven the other way")
    show.set_defaults(func=run_show)

    gen = tsub.add_parser("generate", help="generate a random valid track into the user track folder",
                          description="Generate a random closed track from a seed and save it in the user "
                                      "track folder ($RACERLAB_HOME/tracks, default ~/.racerlab/tracks).")
    gen.add_argument("--seed", type=int, required=True, help="random seed (the same seed gives the same track)")
    gen.add_argument("--length", type=float, default=20.0, help="centre-line length in metres (default 20)")
    gen.add_argument("--width", type=float, default=1.07, help="road width in metres (default 1.07)")
    gen.add_argument("--min-radius", type=float, default=0.6,
                     help="tightest centre-line turn radius in metres (default 0.6)")
    gen.add_argument("--name", default=None, help="track name (default generated_<seed>)")
    gen.add_argument("--force", action="store_true", help="overwrite a user track of the same name")
    gen.set_defaults(func=run_generate)

    fetch = tsub.add_parser("fetch", help="download AWS tracks by name into the user track folder",
                            description="Download AWS DeepRacer route files from the community's public track "
                                        "data (github.com/aws-deepracer-community/deepracer-race-data, "
                                        "raw_data/tracks/npy/), check each against the sha256 racerlab ships and "
                                        "save it in the user track folder, where every command finds it by name. "
                                        "$RACERLAB_AWS_TRACKS_URL points the downloads at a mirror.")
    fetch.add_argument("names", metavar="NAME", nargs="*", help="AWS track names, e.g. reInvent2019_track")
    fetch.add_argument("--all", action="store_true", help="every AWS track racerlab knows (about 1.2 MB)")
    fetch.add_argument("--list", action="store_true", help="list the AWS track names and titles, download nothing")
    fetch.set_defaults(func=run_fetch)

    imp = tsub.add_parser("import", help="copy the AWS route files found in a folder into the user track folder",
                          description="Copy every AWS route file found under a folder you already have (a DRfC "
                                      "or deepracer-simapp checkout, any depth) into the user track folder, each "
                                      "checked against the sha256 racerlab ships.")
    imp.add_argument("folder", type=Path, metavar="DIR", help="the folder to search for .npy route files")
    imp.set_defaults(func=run_import)


def _source(path: Path) -> str:
    from racerlab.track.registry import is_bundled

    return "bundled" if is_bundled(path) else "user"


def run_list(args) -> int:
    from racerlab.track import load
    from racerlab.track.registry import catalogue

    rows = []
    for name, path in sorted(catalogue().items()):
        try:
            t = load(path)
        except Exception as exc:  # noqa: BLE001 - a broken user file is listed, not fatal
            rows.append((name, _source(path), "-", "-", "-", f"unreadable: {str(exc).splitlines()[0]}"))
            continue
        rows.append((name, _source(path), f"{t.length:.2f}", f"{t.width:.2f}", str(t.turns()), str(path)))
    if not rows:
        print("no tracks found")
        return 0
    _print_table(("name", "source", "length_m", "width_m", "turns", "file"), rows)
    return 0


def _print_table(header: tuple[str, ...], rows: list[tuple[str, ...]]) -> None:
    widths = [max(len(r[i]) for r in (header, *rows)) for i in range(len(header))]
    numeric = {2, 3, 4}
    for r in (header, *rows):
        cells = [c.rjust(w) if i in numeric else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths, strict=True))]
        print("  ".join(cells).rstrip())


def run_show(args) -> int:
    from racerlab.cli import OUT_DIR
    from racerlab.track import DEFAULT_TRACK, load
    from racerlab.track.plot import save_track_png

    t = load(args.track or DEFAULT_TRACK, reverse=args.reverse)
    out = args.out or OUT_DIR / "tracks" / f"{t.name}{'_reversed' if args.reverse else ''}.png"
    if out.suffix.lower() != ".png":
        from racerlab.errors import RacerlabError

        raise RacerlabError(f"--out {out}: the picture is a PNG; give a file name ending in .png")
    save_track_png(t, out)
    print(describe(t))
    print(f"picture: {out.resolve()}")
    return 0


def run_fetch(args) -> int:
    from racerlab.errors import RacerlabError
    from racerlab.track import user_dir
    from racerlab.track.aws import catalogue, fetch, resolve_names

    if args.list:
        _print_table(("name", "title"), [(t.name, t.title) for t in catalogue().values()])
        return 0
    if not args.names and not args.all:
        raise RacerlabError("name the tracks to fetch (e.g. `racerlab tracks fetch reInvent2019_track`), "
                            "or use --all; --list shows the names")
    wanted = resolve_names(args.names, everything=args.all)
    folder = user_dir()
    done, kept = fetch(wanted, folder, report=lambda t, path: print(f"fetched {t.name} ({t.title}): {path}"))
    for path in kept:
        print(f"already there: {path}")
    print(f"{len(done)} downloaded, {len(kept)} already there, in {folder}; "
          f"use them by name, e.g. `racerlab tracks show {wanted[0].name}`")
    return 0


def run_import(args) -> int:
    from racerlab.track import user_dir
    from racerlab.track.aws import import_folder

    folder = user_dir()
    res = import_folder(args.folder, folder)
    for path in res.copied:
        print(f"imported {path.stem}: {path}")
    for path in res.mismatched:
        print(f"skipped {path}: not the AWS file of that name (its sha256 differs); "
              f"`racerlab tracks fetch {path.stem}` downloads the real one", file=sys.stderr)
    print(f"{len(res.copied)} imported, {len(res.already)} already there, {len(res.mismatched)} skipped "
          f"(different bytes), {res.other} other .npy files left alone; into {folder}")
    return 0 if res.copied or res.already else 1


def describe(t) -> str:
    """One line per fact about a track, as `tracks show` prints it."""
    way = "counter-clockwise" if t.is_ccw else "clockwise"
    waypoints = t.num_waypoints - (1 if t.closed else 0)
    return "\n".join([
        f"track: {t.name}" + (" (reversed)" if t.reversed else ""),
        f"length: {t.length:.2f} m",
        f"width: {t.width:.2f} m" + (f" ({t.widths.min():.2f}-{t.widths.max():.2f})"
                                     if t.widths.max() - t.widths.min() > 0.01 else ""),
        f"turns: {t.turns()}",
        f"waypoints: {waypoints}" + (" + closing copy of waypoint 0" if t.closed else ""),
        f"direction: {way}" + ("" if t.closed else " (open track)"),
    ])


def run_generate(args) -> int:
    import numpy as np

    from racerlab.errors import RacerlabError
    from racerlab.track import user_dir
    from racerlab.track.generate import generate

    name = args.name or f"generated_{args.seed}"
    if not name.replace("_", "").replace("-", "").isalnum():
        raise RacerlabError(f"--name {name!r}: use letters, digits, '_' and '-' only")
    path = user_dir() / f"{name}.npy"
    if path.exists() and not args.force:
        raise RacerlabError(f"{path} already exists; pick another --name or add --force to overwrite it")
    t = generate(args.seed, length=args.length, width=args.width, min_radius=args.min_radius, name=name)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.part")  # not a track suffix, so never listed half-written
    with open(tmp, "wb") as f:
        np.save(f, t.as_array())
    tmp.replace(path)
    print(describe(t))
    print(f"saved: {path}  (use it by name: {name}; draw it with `racerlab tracks show {name}`)")
    return 0
