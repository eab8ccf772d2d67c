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
import tempfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from racerlab.errors import ConfigError, RacerlabError

S3_HINT = "pip install 'racerlab[s3]'"
SHA_KEY = "racerlab-sha256"
PART_BYTES = 8 << 20


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
    session = boto3.Session(profile_name=profile, region_name=region)
    endpoint = endpoint_url or os.environ.get("AWS_ENDPOINT_URL") or None
    return session.client("s3", endpoint_url=endpoint)


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


def download_tree(s3, url: S3Url, dest: Path, progress=print) -> int:
    """Download every object under `url` into `dest` (keys relative to the prefix), hash-checked."""
    base = url.key("")
    paginator = s3.get_paginator("list_objects_v2")
    config, n = _transfer_config(), 0
    for page in paginator.paginate(Bucket=url.bucket, Prefix=base):
        for obj in page.get("Contents", []):
            rel = obj["Key"][len(base):]
            parts = PurePosixPath(rel).parts
            if not rel or rel.endswith("/") or ".." in parts or rel.startswith("/"):
                continue  # folder markers; keys that would leave the folder are never written
            target = dest.joinpath(*parts)
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.part-")
            os.close(fd)
            try:
                s3.download_file(url.bucket, obj["Key"], tmp, Config=config)
                want = (_remote(s3, url.bucket, obj["Key"]) or {}).get("Metadata", {}).get(SHA_KEY)
                if want and sha256_file(Path(tmp)) != want:
                    raise RacerlabError(f"s3://{url.bucket}/{obj['Key']}: the download does not match the object's "
                                        "SHA-256; run the pull again")
                os.replace(tmp, target)
            finally:
                Path(tmp).unlink(missing_ok=True)
            n += 1
            progress(f"  {rel}")
    if n == 0:
        raise RacerlabError(f"s3://{url.bucket}/{base}: no objects under this prefix; check the bucket and prefix")
    return n


def push(model_dir, url: str, checkpoint: str | int = "best", profile=None, region=None, endpoint_url=None,
         progress=print) -> dict[str, int]:
    """Export `model_dir` in DRfC's layout and upload it under `url` (s3://bucket/prefix)."""
    from racerlab.exchange.export import write_virtual_tree
    from racerlab.exchange.local import load_local_model

    target = S3Url.parse(url)
    model = load_local_model(model_dir, checkpoint)
    s3 = client(profile, region, endpoint_url)
    with tempfile.TemporaryDirectory(prefix="racerlab-s3-") as tmp:
        write_virtual_tree(model, Path(tmp))
        try:
            return upload_tree(s3, Path(tmp), target, progress)
        except _errors() as exc:
            raise _describe(exc, url) from None


def pull(url: str, dest, profile=None, region=None, endpoint_url=None, progress=print) -> int:
    """Download everything under `url` into `dest`; returns the number of files."""
    source = S3Url.parse(url)
    s3 = client(profile, region, endpoint_url)
    try:
        return download_tree(s3, source, Path(dest), progress)
    except _errors() as exc:
        raise _describe(exc, url) from None
