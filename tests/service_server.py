"""A real `asset-preview serve` process on a free loopback port, for the service tests."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]


# The shared service's limits (conftest.py `server`), which test_service.py probes.
UPLOAD_LIMIT = 16 * 2**20
MAX_QUEUE = 6
UNPACKED_LIMIT = 64 * 2**20
SERVER_ENV = {"ASSET_PREVIEW_MAX_ARCHIVE_FILES": "64", "ASSET_PREVIEW_MAX_QUEUE": str(MAX_QUEUE),
              "ASSET_PREVIEW_MAX_UNPACKED_BYTES": str(UNPACKED_LIMIT),
              "ASSET_PREVIEW_MAX_TRIANGLES": "10000",  # the bunny (16k) is over, the samples under
              "ASSET_PREVIEW_MAX_TEXTURE_PIXELS": str(2048 * 2048),
              "ASSET_PREVIEW_CLIENT_SHARE": "1"}  # every test client is 127.0.0.1: one client
ARGS = ("--workers", "2", "--no-seed", "--max-upload-bytes", str(UPLOAD_LIMIT))

def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    def __init__(self, cache: Path, *args: str, env: dict | None = None, log: Path | None = None):
        self.cache = Path(cache)
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = log or self.cache.parent / f"server-{self.port}.log"
        full_env = {k: v for k, v in os.environ.items() if not k.startswith("ASSET_PREVIEW_")}
        full_env.update(env or {})
        cmd = [sys.executable, "-m", "cli.main", "serve", "--port", str(self.port),
               "--cache", str(self.cache), *args]
        self._log_file = open(self.log, "ab")
        self.proc = subprocess.Popen(cmd, cwd=ROOT, env=full_env, stdout=self._log_file,
                                     stderr=subprocess.STDOUT)
        self.client = httpx.Client(base_url=self.url, timeout=60)

    def wait_ready(self, timeout: float = 90) -> dict:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited ({self.proc.returncode}); log:\n{self.log.read_text()[-3000:]}")
            try:
                r = self.client.get("/readyz")
                if r.status_code == 200:
                    return r.json()
            except httpx.TransportError:
                pass
            time.sleep(0.2)
        raise TimeoutError(f"server not ready in {timeout} s; log:\n{self.log.read_text()[-3000:]}")

    def wait_status(self, asset_id: str, timeout: float = 120) -> dict:
        """Poll until the asset is no longer baking."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            rec = self.client.get(f"/assets/{asset_id}").json()
            if rec["status"] != "baking":
                return rec
            time.sleep(0.1)
        raise TimeoutError(f"asset {asset_id} still baking after {timeout} s")

    def worker_jobs(self) -> int:
        return sum(w["jobs"] for w in self.client.get("/readyz").json()["workers"])

    def stop(self) -> None:
        self.client.close()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log_file.close()
