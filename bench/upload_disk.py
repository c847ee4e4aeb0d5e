"""`asset-preview bench upload_disk`: bytes on disk an upload costs, folder by folder.

A real server (subprocess, loopback) takes one zipped upload (default: IridescenceLamp, five
files, 5 MB: the 3.7 MB-class case of issue 29), bakes it, serves the card's thumbnail and what
the page's detail view asks for (a 512 px still and a 24-frame WebP turntable); every folder of
its cache is measured (`du`-style, allocated blocks) before and after.
"""
from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

from bench.service import ROOT, free_port, wait_http

ASSETS = ROOT / "tests" / "assets"
DEFAULT = ASSETS / "gltf-samples" / "IridescenceLamp" / "glTF"


def disk_bytes(folder: Path) -> dict[str, int]:
    """Allocated bytes per folder two levels under `folder` (service/assets, assets/<kind>, ...)."""
    out: dict[str, int] = {}
    for f in folder.rglob("*"):
        if f.is_file() and not f.is_symlink():
            rel = f.relative_to(folder).parts
            key = "/".join(rel[:2]) if len(rel) > 2 else rel[0]
            out[key] = out.get(key, 0) + f.stat().st_blocks * 512
    return out


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--folder", type=Path, default=DEFAULT, help="folder zipped as the upload")


def run(args: argparse.Namespace) -> int:
    import httpx
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(args.folder.iterdir()):
            z.write(f, f.name)
    upload = buf.getvalue()
    tmp = Path(tempfile.mkdtemp(prefix="bench-disk-"))
    cache, port = tmp / "cache", free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("ASSET_PREVIEW_")}
    log = open(tmp / "server.log", "wb")
    server = subprocess.Popen([sys.executable, "-m", "cli.main", "serve", "--port", str(port), "--cache", str(cache),
                               "--workers", "1", "--no-seed", "--log-level", "warning"],
                              cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    try:
        wait_http(f"http://127.0.0.1:{port}/readyz")
        client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=600)
        before = disk_bytes(cache)
        r = client.post("/assets", files={"file": (args.folder.name + ".zip", upload)})
        assert r.status_code == 201, r.text
        asset_id = r.json()["id"]
        while client.get(f"/assets/{asset_id}").json()["status"] == "baking":
            time.sleep(0.5)
        stages = {"upload + bake": disk_bytes(cache)}
        views: tuple[tuple[str, dict[str, str]], ...] = (
            ("card thumbnail", {}), ("page still", {"size": "512"}),
            ("page turntable", {"turntable": "24", "format": "webp", "size": "512"}))
        for what, params in views:
            assert client.get(f"/assets/{asset_id}/thumbnail", params=params).status_code == 200
            stages[what] = disk_bytes(cache)
    finally:
        server.terminate()
        server.wait(30)
    rows = {name: {k: v - before.get(k, 0) for k, v in after.items() if v - before.get(k, 0)}
            for name, after in stages.items()}
    print(f"upload {len(upload)} bytes ({args.folder.name}, zipped)")
    for name, row in rows.items():
        print(f"after {name}: {sum(row.values()) / 2**20:.1f} MiB  " +
              ", ".join(f"{k} {v / 2**20:.2f}" for k, v in sorted(row.items())))
    print(json.dumps({"upload_bytes": len(upload), "stages": rows}))
    return 0
