"""The library job (`asset-bake --thumbnails --executor ray`) on a local 3-node Ray cluster on
loopback (a head and two worker nodes, token authentication on) that loses a worker node
mid-run: every asset done exactly once, rendered in the Ray task that baked it, the cache
whole (bakes and thumbnails), no half-written file in DIR, the job finished."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from PIL import Image

from bench.scale import _perturb
from pipeline.cache import MANIFEST, Cache

pytestmark = pytest.mark.slow
SAMPLES = ("gltf/Duck.glb", "gltf/BoxTextured.glb", "mesh/torus.STL")
COPIES = 14


def _library(assets: Path, root: Path) -> list[Path]:
    """The samples and perturbed copies (each its own content key)."""
    files = []
    for rel in SAMPLES:
        src = assets / rel
        (root / src.parent.name).mkdir(parents=True, exist_ok=True)
        data = src.read_bytes()
        for i in range(COPIES):
            copy = root / src.parent.name / f"{src.stem}.c{i:02d}{src.suffix}"
            changed = _perturb(data, src.suffix.lower(), i)
            assert changed is not None
            copy.write_bytes(changed)
            files.append(copy)
    return files


def _rows(out: str) -> list[dict]:
    """stdout: one JSON result per line and nothing else (Ray's notices go to stderr)."""
    rows = []
    for line in filter(str.strip, out.splitlines()):
        try:
            rows.append(json.loads(line))
        except ValueError:
            pytest.fail(f"not a result line on stdout: {line!r}")
    return rows


def _manifest(th: Path) -> dict:
    try:
        return json.loads((th / "manifest.json").read_text())["assets"]
    except (FileNotFoundError, ValueError):
        return {}


def test_library_job_survives_a_lost_worker_node(assets, tmp_path):
    pytest.importorskip("ray")
    from bench.cluster import LocalCluster

    files = _library(assets, tmp_path / "LIB")
    cache, th = tmp_path / "cache", tmp_path / "th"
    cmd = [sys.executable, "-m", "cli.bake", str(tmp_path / "LIB"), "--cache", str(cache), "--thumbnails",
           str(th), "--size", "48", "--json", "--executor", "ray"]
    with LocalCluster(workers=2) as cluster:  # stopped on the way out, pass or fail
        bound = cluster.listening()
        assert bound and all(a.removeprefix("[::ffff:").startswith("127.0.0.1") for a in bound), bound
        env = cluster.driver_env()
        assert env["RAY_AUTH_MODE"] == "token"
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                cwd=Path(__file__).resolve().parent.parent)
        try:
            end = time.monotonic() + 300
            while len(_manifest(th)) < len(files) // 4 and proc.poll() is None and time.monotonic() < end:
                time.sleep(0.05)
            assert proc.poll() is None, "the job ended before a node could be killed"
            done_at_kill = len(_manifest(th))
            cluster.kill_worker(0)
            out, err = proc.communicate(timeout=600)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        assert done_at_kill < len(files)
        cluster.wait_nodes(2)  # the GCS too counts the node lost: the head and one worker node
        assert proc.returncode == 0, err[-3000:]

        rows = _rows(out)
        paths = [r["path"] for r in rows]
        assert sorted(paths) == sorted(map(str, files))  # each asset exactly once
        # `cached`: a task of the lost node that had stored its bake (and maybe its render)
        # before the node died; its retry finds them in the cache. Only those in flight then.
        assert {r["status"] for r in rows} <= {"baked", "cached"}
        assert sum(r["status"] == "cached" for r in rows) <= 8  # Ray's window: 4 per CPU
        manifest = _manifest(th)
        assert sorted(manifest) == sorted(map(str, files))
        for entry in manifest.values():
            assert entry["status"] in ("rendered", "cached"), entry
            assert entry["by"]["node"], entry  # rendered in a Ray task, not in the driver
            [name] = entry["files"]
            with Image.open(th / name) as im:
                assert im.size == (48, 48)
        assert not list(th.rglob("*.tmp*"))

        # The cache: one whole entry per asset, nothing half-written among the entries.
        keys = {r["key"] for r in rows}
        assert len(keys) == len(files)
        store = Cache(cache)
        entries = sorted((cache / "assets").iterdir())
        assert {p.name for p in entries} == keys
        for entry in entries:
            assert store.load("assets", entry.name) is not None, entry
            listed = json.loads((entry / MANIFEST).read_bytes())["files"]
            assert {f.name for f in entry.iterdir()} == {MANIFEST, *listed}
        thumbs = sorted((cache / "thumbnails").iterdir())
        assert {p.name for p in thumbs} == {e["thumbnail"] for e in manifest.values()}
        for entry in thumbs:
            assert store.load("thumbnails", entry.name) is not None, entry
            assert {f.name for f in entry.iterdir()} == {MANIFEST, "thumbnail.png"}

        # Resumable on what is left of the cluster: nothing baked or rendered again.
        again = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600,
                               cwd=Path(__file__).resolve().parent.parent)
        assert again.returncode == 0, again.stderr[-3000:]
        rows = _rows(again.stdout)
        assert len(rows) == len(files)
        assert {(r["status"], r["thumbnail"]["status"]) for r in rows} == {("cached", "kept")}
        groups = list(cluster.groups)
    from bench.cluster import _group_alive
    assert not any(map(_group_alive, groups))  # every process of the cluster gone (zombies aside)
    shutil.rmtree(tmp_path / "LIB")
