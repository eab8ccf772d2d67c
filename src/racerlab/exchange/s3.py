"""`racerlab s3 push | pull`: a model in DRfC's bucket layout, over any S3-compatible endpoint.

Push exports the model's DRfC tree (`export.write_virtual_tree`) and uploads it under `s3://bucket/prefix/`;
pull downloads every object under a prefix into a folder, ready for `racerlab import`. boto3 follows the
AWS CLI's conventions: `--profile` / `AWS_PROFILE`, `--region` / `AWS_DEFAULT_REGION`, and
`--endpoint-url` / `AWS_ENDPOINT_URL` for MinIO, DRfC's local MinIO or any other S3-compatible server.

- Large files go up and down in parts (boto3's managed transfer, 8 MiB parts).
- Every object carries the SHA-256 of its content in its metadata (`x-amz-meta-racerlab-sha256`). A push
  checks each upload against it with a HEAD request; a pull checks each download.
- A push that was interrupted can be run again: objects already there with the right size and hash are
  skipped, and multipart uploads left unfinished under the prefix are aborted first.
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from racerlab.errors import ConfigError, RacerlabError
from racerlab.logs import scratch_dir
from racerlab.logs.scratch import sweep

S3_HINT = "pip install 'racerlab[s3]'"
SHA_KEY = "racerlab-sha256"
PART_BYTES = 8 << 20
PART_MARK = ".part-"  # `.<name>.part-<pid>-<random>`: a download in progress
MAX_NAME_BYTES = 255  # a file name on the common file systems
MAX_PATH_BYTES = 1024  # a key below the prefix, written as a path under the folder


@dataclass(frozen=True)
class S3Url:
    bucket: str
    prefix: str  # no leading or trailing slash

    @classmethod
    def parse(cls, url: str) -> S3Url:
        if not url.startswith("s3://") or not url[5:].split("/", 1)[0]:
            raise ConfigError(f"{url}: not an S3 URL; write s3://bucket/prefix")
        bucket, _, prefix = url[5:].partition("/")
        return cls(bucket, prefix.strip("/"))

    def key(self, relative: str) -> str:
        return f"{self.prefix}/{relative}" if self.prefix else relative


def client(profile: str | None = None, region: str | None = None, endpoint_url: str | None = None):
    try:
        import boto3
    except ImportError:
        raise RacerlabError(f"S3 transfers need boto3; {S3_HINT}") from None
    from botocore.exceptions import BotoCoreError

    endpoint = endpoint_url or os.environ.get("AWS_ENDPOINT_URL") or None
    if endpoint and not re.match(r"^https?://[^/\s]+", endpoint):
        what = "--endpoint-url" if endpoint_url else "AWS_ENDPOINT_URL"
        raise ConfigError(f"{what} {endpoint}: not an http(s) URL; write it with its scheme, e.g. "
                          "http://localhost:9000 for MinIO or https://s3.eu-west-1.amazonaws.com")
    try:
        session = boto3.Session(profile_name=profile, region_name=region)
        return session.client("s3", endpoint_url=endpoint)
    except BotoCoreError as exc:
        name = profile or os.environ.get("AWS_PROFILE")
        hint = (f"--profile {name}: no such profile in ~/.aws/config or ~/.aws/credentials; list them with `aws "
                "configure list-profiles`") if type(exc).__name__ == "ProfileNotFound" else f"{exc}"
        raise RacerlabError(f"S3: {hint}") from None


def _transfer_config():
    from boto3.s3.transfer import TransferConfig

    return TransferConfig(multipart_threshold=PART_BYTES, multipart_chunksize=PART_BYTES)


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _errors():
    from botocore.exceptions import BotoCoreError, ClientError

    return BotoCoreError, ClientError


def _describe(exc, url: str) -> RacerlabError:
    code = getattr(exc, "response", {}).get("Error", {}).get("Code", "") if hasattr(exc, "response") else ""
    hint = {"NoSuchBucket": "create the bucket first or check its name",
            "AccessDenied": "check the profile's credentials and the bucket policy",
            "InvalidAccessKeyId": "check the profile's credentials"}.get(code, "check --endpoint-url, --profile and "
                                                                             "--region")
    return RacerlabError(f"{url}: {type(exc).__name__}: {str(exc).splitlines()[0]}; {hint}")


def _remote(s3, bucket: str, key: str) -> dict | None:
    _, client_error = _errors()
    try:
        return s3.head_object(Bucket=bucket, Key=key)
    except client_error as exc:
        if exc.response.get("Error", {}).get("Code") in ("404", "NoSuchKey", "NotFound"):
            return None
        raise


def _abort_unfinished(s3, url: S3Url) -> int:
    listing = s3.list_multipart_uploads(Bucket=url.bucket, Prefix=url.key(""))
    uploads = listing.get("Uploads", [])
    for u in uploads:
        s3.abort_multipart_upload(Bucket=url.bucket, Key=u["Key"], UploadId=u["UploadId"])
    return len(uploads)


def upload_tree(s3, root: Path, url: S3Url, progress=print) -> dict[str, int]:
    """Upload every file under `root` to `url`; returns counts of uploaded and skipped files."""
    counts = {"uploaded": 0, "skipped": 0, "aborted_multipart": _abort_unfinished(s3, url)}
    config = _transfer_config()
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        rel = path.relative_to(root).as_posix()
        key, digest, size = url.key(rel), sha256_file(path), path.stat().st_size
        head = _remote(s3, url.bucket, key)
        if head and head.get("ContentLength") == size and head.get("Metadata", {}).get(SHA_KEY) == digest:
            counts["skipped"] += 1
            continue
        s3.upload_file(str(path), url.bucket, key, Config=config, ExtraArgs={"Metadata": {SHA_KEY: digest}})
        head = _remote(s3, url.bucket, key)
        if not head or head.get("ContentLength") != size or head.get("Metadata", {}).get(SHA_KEY) != digest:
            raise RacerlabError(f"s3://{url.bucket}/{key}: the uploaded object does not match {path} (size or "
                                "SHA-256); run the push again")
        counts["uploaded"] += 1
        progress(f"  {rel} ({size / 2**20:.1f} MiB)")
    return counts


def _listing(s3, url: S3Url) -> list[tuple[str, tuple[str, ...]]]:
    """(key, relative path parts) of every object under `url` that can be written as a file below the folder,
    checked whole before anything is written: over-long names and a key that is both a file and a folder
    (`a` and `a/b`) are refused in one line."""
    base, out = url.key(""), []
    for page in s3.get_paginator("list_objects_v2").paginate(Bucket=url.bucket, Prefix=base):
        for obj in page.get("Contents", []):
            rel = obj["Key"][len(base):]
            parts = PurePosixPath(rel).parts
            if not rel or rel.endswith("/") or ".." in parts or rel.startswith("/"):
                continue  # folder markers; keys that would leave the folder are never written
            too_long = [p for p in parts if len(p.encode()) > MAX_NAME_BYTES - 16]  # room for `.part-` names
            if too_long or len(rel.encode()) > MAX_PATH_BYTES:
                raise RacerlabError(f"s3://{url.bucket}/{obj['Key']}: a key too long for a file name here (at most "
                                    f"{MAX_NAME_BYTES - 16} bytes a part, {MAX_PATH_BYTES} in all); rename the "
                                    "object or pull a narrower prefix")
            out.append((obj["Key"], parts))
    files = {parts for _, parts in out}
    for key, parts in out:
        for k in range(1, len(parts)):
            if parts[:k] in files:
                raise RacerlabError(f"s3://{url.bucket}/{key}: {'/'.join(parts[:k])} is both an object and a "
                                    "folder under this prefix; a folder cannot hold both. Remove one of them")
    return out


def download_tree(s3, url: S3Url, dest: Path, progress=print) -> int:
    """Download every object under `url` into `dest` (keys relative to the prefix), hash-checked."""
    config, n, listing = _transfer_config(), 0, _listing(s3, url)
    if not listing:
        raise RacerlabError(f"s3://{url.bucket}/{url.key('')}: no objects under this prefix; check the bucket "
                            "and prefix")
    for key, parts in listing:
        target = dest.joinpath(*parts)
        target.parent.mkdir(parents=True, exist_ok=True)
        if target.is_dir():
            raise RacerlabError(f"{target}: a folder where s3://{url.bucket}/{key} goes; pull into a new folder")
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}{PART_MARK}{os.getpid()}-")
        os.close(fd)
        try:
            s3.download_file(url.bucket, key, tmp, Config=config)
            want = (_remote(s3, url.bucket, key) or {}).get("Metadata", {}).get(SHA_KEY)
            if want and sha256_file(Path(tmp)) != want:
                raise RacerlabError(f"s3://{url.bucket}/{key}: the download does not match the object's "
                                    "SHA-256; run the pull again")
            os.replace(tmp, target)
        finally:
            Path(tmp).unlink(missing_ok=True)
        n += 1
        progress(f"  {'/'.join(parts)}")
    return n


def _remove_dead_parts(dest: Path) -> None:
    """Remove the `.part` files that killed pulls left under `dest`."""
    for folder, _, _ in os.walk(dest):
        sweep(Path(folder), lambda name: name.startswith(".") and PART_MARK in name)


def check_pull_destination(dest: Path, force: bool) -> None:
    if dest.exists() and not dest.is_dir():
        raise RacerlabError(f"{dest}: a file of that name exists; pull into a folder")
    if dest.is_dir():
        _remove_dead_parts(dest)
        if not force and any(p.is_file() or p.is_symlink() for p in dest.rglob("*")):
            raise RacerlabError(f"{dest}: not empty; pull into a new folder, or add --force to overwrite the files "
                                "the pull brings")


def push(model_dir, url: str, checkpoint: str | int = "best", profile=None, region=None, endpoint_url=None,
         progress=print) -> dict[str, int]:
    """Export `model_dir` in DRfC's layout and upload it under `url` (s3://bucket/prefix)."""
    from racerlab.exchange.export import write_virtual_tree
    from racerlab.exchange.local import open_for_export

    target = S3Url.parse(url)
    model, policy = open_for_export(model_dir, checkpoint)
    s3 = client(profile, region, endpoint_url)
    with scratch_dir("s3-push") as tmp:
        try:
            write_virtual_tree(model, policy, tmp)
            return upload_tree(s3, tmp, target, progress)
        except _errors() as exc:
            raise _describe(exc, url) from None
        except OSError as exc:
            raise RacerlabError(f"{tmp}: cannot write the DRfC tree to push ({exc.strerror}); free some disk "
                                "space or set RACERLAB_TMPDIR to a folder with room") from None


def pull(url: str, dest, profile=None, region=None, endpoint_url=None, progress=print, force: bool = False) -> int:
    """Download everything under `url` into `dest` (a new or empty folder, or any with `force`); returns the
    number of files."""
    source = S3Url.parse(url)
    dest = Path(dest)
    check_pull_destination(dest, force)
    s3 = client(profile, region, endpoint_url)
    try:
        return download_tree(s3, source, dest, progress)
    except _errors() as exc:
        raise _describe(exc, url) from None
    except OSError as exc:
        raise RacerlabError(f"{dest}: cannot write the download ({exc.strerror}); free some disk space and pull "
                            "again") from None
