"""Real servers on the loopback address for the tests that read URLs: an S3 API (moto's
server, ``moto_server``, in its own process, with IAM authentication on) and a plain HTTP
server (the standard library's, with byte ranges, in a thread)."""

from __future__ import annotations

import contextlib
import email.utils
import functools
import http.server
import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import pytest

BIN = Path(sys.executable).parent


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class S3Server:
    """A running S3 API: its endpoint, a user who may read and write everything, and one who
    may list but not read objects."""

    endpoint: str
    key: str
    secret: str
    denied_key: str
    denied_secret: str

    def env(self, *, key: str | None = None, secret: str | None = None) -> dict[str, str]:
        return {"AWS_ACCESS_KEY_ID": key or self.key,
                "AWS_SECRET_ACCESS_KEY": secret or self.secret,
                "AWS_ENDPOINT_URL": self.endpoint, "AWS_DEFAULT_REGION": "us-east-1"}

    def client(self) -> Any:
        import boto3

        return boto3.client("s3", endpoint_url=self.endpoint, region_name="us-east-1",
                            aws_access_key_id=self.key, aws_secret_access_key=self.secret)

    def bucket(self, name: str) -> str:
        with contextlib.suppress(Exception):
            self.client().create_bucket(Bucket=name)
        return name

    def upload(self, bucket: str, key: str, data: bytes | Path) -> str:
        body = data.read_bytes() if isinstance(data, Path) else data
        self.client().put_object(Bucket=self.bucket(bucket), Key=key, Body=body)
        return f"s3://{bucket}/{key}"

    def upload_tree(self, bucket: str, prefix: str, root: Path) -> None:
        for path in sorted(root.rglob("*")):
            if path.is_file():
                self.upload(bucket, f"{prefix}/{path.relative_to(root).as_posix()}", path)


def _wait_for(port: int, proc: subprocess.Popen[bytes]) -> None:
    for _ in range(400):
        if proc.poll() is not None:
            raise RuntimeError("moto_server ended as it started")
        with contextlib.suppress(OSError):
            socket.create_connection(("127.0.0.1", port), 0.2).close()
            return
        time.sleep(0.05)
    raise RuntimeError("moto_server did not listen")


@contextlib.contextmanager
def s3_server() -> Iterator[S3Server]:
    pytest.importorskip("s3fs", reason="the remote extra (s3fs) is not installed")
    pytest.importorskip("moto", reason="moto[server] is not installed")
    if shutil.which("moto_server", path=str(BIN)) is None:
        pytest.skip("moto_server (moto[server]) is not installed")
    import boto3

    port = free_port()
    # the first 6 requests (creating the users) run unauthenticated, every later one is checked
    env = {**os.environ, "INITIAL_NO_AUTH_ACTION_COUNT": "6"}
    proc = subprocess.Popen([str(BIN / "moto_server"), "-H", "127.0.0.1", "-p", str(port)],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_for(port, proc)
        endpoint = f"http://127.0.0.1:{port}"
        iam = boto3.client("iam", endpoint_url=endpoint, region_name="us-east-1",
                           aws_access_key_id="setup", aws_secret_access_key="setup")
        keys = []
        for user, actions in (("fleet", ["s3:*"]), ("lister", ["s3:ListBucket"])):
            iam.create_user(UserName=user)
            iam.put_user_policy(UserName=user, PolicyName="p", PolicyDocument=json.dumps({
                "Version": "2012-10-17", "Statement": [{"Effect": "Allow", "Action": actions,
                                                        "Resource": "*"}]}))
            keys.append(iam.create_access_key(UserName=user)["AccessKey"])
        yield S3Server(endpoint, keys[0]["AccessKeyId"], keys[0]["SecretAccessKey"],
                       keys[1]["AccessKeyId"], keys[1]["SecretAccessKey"])
    finally:
        proc.terminate()
        proc.wait(10)


class RangeHandler(http.server.SimpleHTTPRequestHandler):
    """A plain static file server that answers byte ranges (as nginx does) and logs nothing;
    ``failures`` drops that many GETs of each file before serving it (a flaky network)."""

    failures: ClassVar[dict[str, int]] = {}

    def log_message(self, format: str, *args: Any) -> None:
        pass

    def do_GET(self) -> None:
        left = self.failures.get(self.path, 0)
        if left:
            self.failures[self.path] = left - 1
            self.send_response(503)
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        spec = self.headers.get("Range")
        path = Path(self.translate_path(self.path))
        if not spec or not path.is_file():
            super().do_GET()
            return
        data = path.read_bytes()
        lo_text, _, hi_text = spec.removeprefix("bytes=").partition("-")
        lo = int(lo_text)
        hi = min(int(hi_text), len(data) - 1) if hi_text else len(data) - 1
        if lo >= len(data):
            self.send_response(416)
            self.send_header("Content-Range", f"bytes */{len(data)}")
            self.end_headers()
            return
        self.send_response(206)
        self.send_header("Content-Range", f"bytes {lo}-{hi}/{len(data)}")
        self.send_header("Content-Length", str(hi - lo + 1))
        self.send_header("Accept-Ranges", "bytes")
        self.send_header("Last-Modified", email.utils.formatdate(path.stat().st_mtime,
                                                                 usegmt=True))
        self.end_headers()
        self.wfile.write(data[lo:hi + 1])


class PlainHandler(http.server.SimpleHTTPRequestHandler):
    """A static file server that answers no byte ranges (the standard library's own: a Range
    header is ignored, the whole file sent), and logs nothing."""

    def log_message(self, format: str, *args: Any) -> None:
        pass


@contextlib.contextmanager
def http_server(root: Path, *, ranges: bool = True) -> Iterator[str]:
    """Serve ``root`` on the loopback address; yields the base URL (no trailing slash).
    ``ranges`` False: a server that answers no byte ranges."""
    pytest.importorskip("fsspec", reason="the remote extra (fsspec) is not installed")
    pytest.importorskip("aiohttp", reason="the remote extra (aiohttp) is not installed")
    handler = functools.partial(RangeHandler if ranges else PlainHandler, directory=str(root))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()
