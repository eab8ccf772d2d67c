"""`racerlab export | import | s3`: models to and from the car, DRoA, DRfC and S3 (racerlab.exchange)."""

from __future__ import annotations

from pathlib import Path

from racerlab.errors import RacerlabError

# what each of `racerlab export`'s destinations writes
EXPORT_FILES = ("--car writes <model>-car.tar.gz (model_metadata.json + agent/model.pb); --onnx writes "
                "<model>-onnx.tar.gz (model_metadata.json + model.onnx); --tflite writes <model>-tflite.tar.gz, the "
                "community car's model folder (model.pb, model.tflite, model_metadata.json, checksum.txt); --droa "
                "writes <model>-droa.tar.gz for DRoA's Import model; --drfc DIR writes the folder layout DRfC uploads "
                "and trains from.")


def register(sub) -> None:
    p = sub.add_parser("export", help="export a model for the physical car (TF, ONNX, TFLite), DRoA or DRfC",
                       description=EXPORT_FILES)
    p.add_argument("model", type=Path)
    dest = p.add_mutually_exclusive_group(required=True)
    dest.add_argument("--car", action="store_true", help="the physical car's .tar.gz")
    dest.add_argument("--onnx", action="store_true", help="the policy as ONNX, beside model_metadata.json")
    dest.add_argument("--tflite", action="store_true", help="the community car's TFLite model folder, as a .tar.gz")
    dest.add_argument("--droa", action="store_true", help="DeepRacer-on-AWS's import .tar.gz")
    dest.add_argument("--drfc", type=Path, metavar="DIR", help="DRfC's model folder layout, written into DIR")
    p.add_argument("--checkpoint", default="best", help="best (default), last or an iteration number")
    p.add_argument("-o", "--output",  # a str: a trailing / says "a folder", which Path would drop
                   help="archive path (default: <model>-car.tar.gz, -onnx, -tflite or -droa.tar.gz here; a folder: "
                        "that name in it); never one of the model's files")
    p.add_argument("--force", action="store_true",
                   help="replace an existing file at -o that racerlab export did not write (its own earlier archives "
                        "are replaced without it)")
    p.set_defaults(func=run_export)

    p = sub.add_parser("import", help="make a racerlab model from a console, DRoA, DRfC or car model",
                       description="PATH is a model folder or a .tar.gz/.zip holding model_metadata.json and a "
                                   "TF checkpoint and/or model.pb. Nothing in it is executed: its "
                                   "reward_function.py is kept as text under imported/.")
    p.add_argument("path", type=Path)
    p.add_argument("name", type=Path, nargs="?", help="the new model folder (default: <PATH name>-imported)")
    p.set_defaults(func=run_import)

    p = sub.add_parser("s3", help="push a model to S3 in DRfC's layout, or pull one",
                       description="Works with AWS S3, MinIO and DRfC's local MinIO (--endpoint-url or "
                                   "AWS_ENDPOINT_URL); credentials and region as the AWS CLI finds them.")
    s3 = p.add_subparsers(dest="s3_command", metavar="push|pull", required=True)
    push = s3.add_parser("push", help="upload MODEL to s3://bucket/prefix")
    push.add_argument("model", type=Path)
    push.add_argument("url", metavar="s3://bucket/prefix")
    push.add_argument("--checkpoint", default="best", help="best (default), last or an iteration number")
    pull = s3.add_parser("pull", help="download s3://bucket/prefix into DIR")
    pull.add_argument("url", metavar="s3://bucket/prefix")
    pull.add_argument("dir", type=Path)
    pull.add_argument("--force", action="store_true", help="pull into a folder that is not empty, overwriting the "
                                                           "files the pull brings")
    for q in (push, pull):
        q.add_argument("--profile", help="AWS CLI profile (default: AWS_PROFILE or the default profile)")
        q.add_argument("--region", help="AWS region (default: AWS_DEFAULT_REGION or the profile's)")
        q.add_argument("--endpoint-url", help="S3-compatible endpoint, e.g. http://localhost:9000 for MinIO")
    push.set_defaults(func=run_push)
    pull.set_defaults(func=run_pull)


def run_export(args) -> int:
    from racerlab.cli import require_path

    require_path(args.model, "model folder")
    if args.drfc is not None and args.force:
        raise RacerlabError("--force: --drfc writes only into a new or empty folder; give one")
    from racerlab.exchange import export_car, export_drfc, export_droa, export_onnx, export_tflite

    if args.car:
        out = export_car(args.model, args.output, args.checkpoint, args.force)
        print(f"wrote {out}: upload it in the car's web console (Models > Upload)")
    elif args.onnx:
        out = export_onnx(args.model, args.output, args.checkpoint, args.force)
        print(f"wrote {out}: model.onnx takes the car's inputs by their model.pb names (raw 0-255 NHWC images)")
    elif args.tflite:
        out = export_tflite(args.model, args.output, args.checkpoint, args.force)
        print(f"wrote {out}: on a community-OS car, extract it into /opt/aws/deepracer/artifacts/<name>/ to run this "
              "model.tflite, or upload it in the web console (the car then converts model.pb itself)")
    elif args.droa:
        out = export_droa(args.model, args.output, args.checkpoint, args.force)
        print(f"wrote {out}: upload its contents to DRoA's import bucket and choose Import model")
    else:
        out = export_drfc(args.model, args.drfc, args.checkpoint)
        print(f"wrote {out}: copy it under DRfC's bucket prefix, or `racerlab s3 push {args.model} s3://bucket/prefix`")
    return 0


def run_import(args) -> int:
    from racerlab.cli import require_path

    require_path(args.path, "model folder or archive")
    from racerlab.exchange import import_model

    out = import_model(args.path, args.name)
    kept = out / "imported" / "reward_function.py.txt"
    reward = (f"its own reward function is in {kept} as text" if kept.is_file() else
              "the archive held no reward function (a car archive has none): it trains with racerlab's example "
              "reward until you write one")
    print(f"imported {args.path} into {out}; race it with `racerlab evaluate {out}`, train on with "
          f"`racerlab train {out}` ({reward})")
    return 0


def run_push(args) -> int:
    from racerlab.exchange.s3 import push

    counts = push(args.model, args.url, args.checkpoint, args.profile, args.region, args.endpoint_url)
    print(f"pushed {args.model} to {args.url}: {counts['uploaded']} uploaded, {counts['skipped']} already there")
    return 0


def run_pull(args) -> int:
    from racerlab.exchange.s3 import pull

    n = pull(args.url, args.dir, args.profile, args.region, args.endpoint_url, force=args.force)
    print(f"pulled {n} files into {args.dir}; make a racerlab model of it with `racerlab import {args.dir}`")
    return 0
