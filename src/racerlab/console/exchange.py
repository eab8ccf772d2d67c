"""Routes for model exchange (`racerlab.exchange`): exports of a model for the physical car (TF, ONNX, TFLite),
for DeepRacer-on-AWS and for DRfC, run in the background and offered for download by validated name, and
the import of an uploaded console / DRoA / DRfC / car archive into a new model folder."""

from __future__ import annotations

import re
import shutil
import tempfile
from pathlib import Path
from typing import Annotated

from fastapi import FastAPI, File, Form, Request, UploadFile
from fastapi.responses import FileResponse
from starlette.concurrency import run_in_threadpool

from racerlab.console.security import ConsoleError, check_archive, check_name, inside, plain_file, save_upload

EXPORTS = {"car": "Export for the car", "droa": "Export for DeepRacer-on-AWS", "drfc": "Export for DRfC",
           "onnx": "Export as ONNX", "tflite": "Export for a TFLite car"}
IMPORT_SUFFIXES = (".tar.gz", ".tgz", ".tar")


def ws(request: Request):
    return request.app.state.workspace


def _exports_dir(request: Request, name: str) -> Path:
    return inside(ws(request).state_root / "exports", check_name(name))


def _archive_name(name: str, kind: str) -> str:
    return f"{name}-{kind}.tar.gz"


def _export(kind: str, model_dir: Path, out: Path, checkpoint: str) -> Path:
    from racerlab import exchange

    # the console's exports folder holds its own archives only (older ones lack the export mark): replace them
    if kind == "car":
        return exchange.export_car(model_dir, out, checkpoint, force=True)
    if kind == "droa":
        return exchange.export_droa(model_dir, out, checkpoint, force=True)
    if kind == "onnx":
        return exchange.export_onnx(model_dir, out, checkpoint, force=True)
    if kind == "tflite":
        return exchange.export_tflite(model_dir, out, checkpoint, force=True)
    with tempfile.TemporaryDirectory(prefix="racerlab-drfc-", dir=out.parent) as tmp:
        tree = exchange.export_drfc(model_dir, Path(tmp) / "tree", checkpoint)
        packed = shutil.make_archive(str(Path(tmp) / "packed"), "gztar", root_dir=tree)
        return Path(shutil.move(packed, out))


def register(app: FastAPI) -> None:
    _export_routes(app)
    _import_routes(app)

    @app.get("/api/exchange")
    def exchange_info():
        return {"exports": [{"kind": k, "label": v} for k, v in EXPORTS.items()],
                "import_suffixes": list(IMPORT_SUFFIXES), "upload_limit": app.state.upload_limit}


def _export_routes(app: FastAPI) -> None:
    @app.post("/api/models/{name}/export/{kind}")
    def export(request: Request, name: str, kind: str, checkpoint: str = "best"):
        if kind not in EXPORTS:
            raise ConsoleError(f"export {kind!r}: use one of {', '.join(EXPORTS)}", 404)
        w = ws(request)
        folder = w.folder(name)
        if w.state(name) == "training":
            raise ConsoleError(f"{name}: training; stop it first (its checkpoints change under the export)", 409)
        out_dir = _exports_dir(request, name)

        def job():
            out_dir.mkdir(parents=True, exist_ok=True)
            out = _export(kind, folder.path, out_dir / _archive_name(name, kind), checkpoint)
            return {"archive": out.name, "bytes": out.stat().st_size}

        return w.run_task("export", f"export:{name}:{kind}", job).to_json()

    @app.get("/api/models/{name}/exports")
    def exports(request: Request, name: str):
        ws(request).folder(name)
        d = _exports_dir(request, name)
        found = [(k, d / _archive_name(name, k)) for k in EXPORTS]
        return {"exports": [{"kind": k, "name": p.name, "bytes": p.stat().st_size} for k, p in found if p.is_file()]}

    @app.get("/api/models/{name}/exports/{file}")
    def download(request: Request, name: str, file: str):
        ws(request).folder(name)
        if file not in {_archive_name(name, k) for k in EXPORTS}:
            raise ConsoleError(f"{file!r}: not an export of {name}", 404)
        path = inside(_exports_dir(request, name), file)
        if not plain_file(path):
            raise ConsoleError(f"{name}: no {file} yet; export it first", 404)
        return FileResponse(path, media_type="application/gzip", filename=file)


def _import_routes(app: FastAPI) -> None:
    @app.post("/api/imports")
    async def import_archive(request: Request, file: Annotated[UploadFile, File()], name: Annotated[str, Form()]):
        from racerlab.exchange import import_model

        w = ws(request)
        dst = w.folder(check_name(name), must_exist=False).path
        if dst.exists():
            raise ConsoleError(f"{name}: already exists; choose another name", 409)
        base = re.split(r"[\\/]", file.filename or "")[-1]
        suffix = next((s for s in IMPORT_SUFFIXES if base.lower().endswith(s)), None)
        if suffix is None:
            raise ConsoleError(f"{base!r}: upload a model archive ending in {', '.join(IMPORT_SUFFIXES)}")
        d = w.state_root / "imports"
        d.mkdir(parents=True, exist_ok=True)
        archive = d / (name + suffix)
        size = await save_upload(file, archive, request.app.state.upload_limit)
        try:
            await run_in_threadpool(check_archive, archive)  # reading a whole gzip stream: off the loop
        except ConsoleError:
            archive.unlink(missing_ok=True)
            raise

        def job():
            try:
                return {"model": import_model(archive, dst).name}
            finally:
                archive.unlink(missing_ok=True)

        return {"name": name, "bytes": size, "task": w.run_task("import", f"import:{name}", job).to_json()}
