"""Scale-out on Ray: a local cluster started here bakes a subset of the sample corpus into the same cache as
the local executor, survives a worker killed mid-bake, and serves thumbnails from actors."""
from __future__ import annotations

import hashlib
import io
import json
import os
import re
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from service_server import Server

from cli import bake as bake_cmd
from pipeline.cache import KINDS, MANIFEST, Cache

ENV = ["--env", "neutral", "--face-size", "32"]
# What a manifest records about when and how fast, which no two bakes share.
VOLATILE = ("created", "timings")


def snapshot(root: Path) -> dict[str, object]:
    """Every file of every entry and source record: data files by SHA-256, manifests as JSON
    less the volatile fields."""
    out = {}
    for folder in (*KINDS, "sources"):
        for f in sorted((root / folder).rglob("*")):
            if not f.is_file():
                continue
            rel = f.relative_to(root).as_posix()
            if f.name == MANIFEST:
                m = json.loads(f.read_bytes())
                for k in VOLATILE:
                    m.pop(k)
                for k in ("build_s", "trace_s", "rays_per_s"):
                    m.get("stats", {}).get("interior", {}).pop(k, None)
                out[rel] = m
            else:
                out[rel] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def rows(text: str) -> dict[str, dict]:
    return {r["path"]: r for r in map(json.loads, filter(str.strip, text.splitlines()))}


def test_without_ray_the_executor_fails_clearly(assets, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    code = bake_cmd.main([str(assets / "gltf" / "Duck.glb"), "--executor", "ray",
                          "--cache", str(tmp_path / "cache")])
    err = capsys.readouterr().err
    assert code == 2 and "needs Ray" in err and "pip install 'asset-preview[ray]'" in err
    assert not (tmp_path / "cache").exists()
    from pipeline.executors import ExecutorUnavailable
    from service.workers.ray import RayWorkerPool
    with pytest.raises(ExecutorUnavailable, match="pip install"):
        RayWorkerPool(1, str(tmp_path / "cache"))


def test_unreachable_cluster_fails_fast_and_clearly(assets, tmp_path, capsys):
    pytest.importorskip("ray")
    from service_server import free_port
    start = time.monotonic()
    code = bake_cmd.main([str(assets / "gltf" / "Duck.glb"), "--executor", "ray",
                          "--ray-address", f"127.0.0.1:{free_port()}", "--cache", str(tmp_path)])
    assert code == 2 and "cannot reach the Ray cluster" in capsys.readouterr().err
    assert time.monotonic() - start < 30  # Ray alone would retry for minutes


@pytest.fixture(scope="module")
def cluster():
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, logging_level="WARNING", log_to_driver=False,
             _node_ip_address="127.0.0.1")  # loopback only
    try:
        yield ray.get_runtime_context().gcs_address
    finally:
        ray.shutdown()


# One file of each reader and layout: binary and text glTF (with a .bin beside it), USD with and
# without textures (two stages in one folder), PLY and STL meshes. The heavy samples (the milk
# truck, the bunny, the teapot's payload stages) only make the bake longer, not different.
CORPUS = ("gltf/Duck.glb", "gltf/TestScene.gltf", "gltf/TestScene.bin", "usd/primvar_interpolation.usda",
          "usd/TextureCoordinateTest", "mesh/suzanne.ply", "mesh/torus.STL")


@pytest.fixture(scope="module")
def corpus(assets, tmp_path_factory) -> Path:
    """A representative subset of the sample corpus, every reader once; baking a few hundred
    assets on Ray beside 1 and 2 local workers is `asset-preview bench scale`."""
    import shutil
    root = tmp_path_factory.mktemp("corpus")
    for rel in CORPUS:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        copy = shutil.copytree if (assets / rel).is_dir() else shutil.copy2
        copy(assets / rel, root / rel)
    return root


@pytest.fixture(scope="module")
def local_bake(corpus, tmp_path_factory):
    cache = tmp_path_factory.mktemp("local") / "cache"
    out = io.StringIO()
    from contextlib import redirect_stdout
    with redirect_stdout(out):
        code = bake_cmd.main([str(corpus), *ENV, "--cache", str(cache), "--json"])
    return code, rows(out.getvalue()), cache


@pytest.mark.slow
def test_ray_bake_of_the_corpus_equals_the_local_bake(cluster, local_bake, corpus, tmp_path, capsys):
    local_code, local_rows, local_cache = local_bake
    cache = tmp_path / "cache"
    code = bake_cmd.main([str(corpus), *ENV, "--cache", str(cache), "--json", "--executor", "ray"])
    got = rows(capsys.readouterr().out)
    assert code == local_code == 0
    assert len(got) == len(local_rows) >= 7  # six assets and the environment
    assert {p: (r["status"], r["key"]) for p, r in got.items()} == \
        {p: (r["status"], r["key"]) for p, r in local_rows.items()}
    ours, theirs = snapshot(cache), snapshot(local_cache)
    assert sorted(ours) == sorted(theirs) and any(k.startswith("environments/") for k in ours)
    assert ours == theirs
    # Plain lines too, and a rerun on Ray is all cache hits.
    assert bake_cmd.main([str(corpus), "--cache", str(cache), "--executor", "ray"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(local_rows) - 1 and all(line.startswith("cached ") for line in lines)


class Killer(threading.Thread):
    """Kills (SIGKILL) the first Ray worker seen writing an asset entry into the cache's tmp/
    (its pid is in the folder's name): a death in the middle of a cache write."""

    TMP = re.compile(r"ass-[0-9a-f]{16}-(\d+)-")

    def __init__(self, cache: Path):
        super().__init__(daemon=True)
        self.tmp, self.killed, self.stop = cache / "tmp", [], threading.Event()

    def run(self) -> None:
        while not self.stop.is_set() and not self.killed:
            try:
                names = os.listdir(self.tmp)
            except FileNotFoundError:
                names = []
            for name in names:
                if m := self.TMP.match(name):
                    os.kill(int(m.group(1)), signal.SIGKILL)
                    self.killed.append((int(m.group(1)), name))
                    break
            time.sleep(0.0005)


@pytest.mark.slow
def test_worker_killed_mid_bake_loses_no_asset_and_leaves_no_partial_entry(
        cluster, local_bake, corpus, tmp_path, capsys):
    _, local_rows, _ = local_bake
    cache = tmp_path / "cache"
    killer = Killer(cache)
    killer.start()
    try:
        code = bake_cmd.main([str(corpus), "--cache", str(cache), "--json", "--executor", "ray"])
    finally:
        killer.stop.set()
        killer.join()
    got = rows(capsys.readouterr().out)
    assert killer.killed, "no worker was caught writing an entry"
    assert code == 0, got
    want = {p: r["key"] for p, r in local_rows.items() if r["kind"] == "asset"}
    assert {p: r["key"] for p, r in got.items()} == want  # every asset, its right key
    assert {r["status"] for r in got.values()} <= {"baked", "cached"}
    store = Cache(cache)
    entries = sorted((cache / "assets").iterdir())
    assert {p.name for p in entries} == set(want.values())
    for entry in entries:  # each whole: a manifest, and every file it lists checksums
        assert store.load("assets", entry.name) is not None, entry
        assert {f.name for f in entry.iterdir()} == {MANIFEST, *json.loads((entry / MANIFEST).read_bytes())["files"]}


@pytest.mark.slow
def test_service_on_ray_actors_answers_and_a_killed_actor_costs_one_request(cluster, assets, tmp_path):
    srv = Server(tmp_path / "cache", "--workers", "2", "--no-seed", "--executor", "ray",
                 "--ray-address", cluster)
    try:
        ready = srv.wait_ready(timeout=180)
        assert ready["ready"] and len(ready["workers"]) == 2
        r = srv.client.post("/assets", files={"file": ("Duck.glb", (assets / "gltf/Duck.glb").read_bytes())})
        assert r.status_code == 201, r.text
        duck = srv.wait_status(r.json()["id"])
        assert duck["status"] == "ready", duck
        r = srv.client.get(f"/assets/{duck['id']}/thumbnail", params={"size": 64})
        img = np.asarray(Image.open(io.BytesIO(r.content)).convert("RGB"), np.float32)
        assert r.status_code == 200 and img.std() > 4 and len(np.unique(img[..., 0])) > 16

        out = {}
        t = threading.Thread(target=lambda: out.setdefault("r", srv.client.get(
            f"/assets/{duck['id']}/thumbnail", params={"size": 1024, "yaw": 41})))
        t.start()
        victim, end = None, time.monotonic() + 60
        while victim is None and time.monotonic() < end:
            busy = [w for w in srv.client.get("/readyz").json()["workers"] if w["op"] == "render"]
            victim = busy[0]["pid"] if busy and busy[0]["pid"] else None
            time.sleep(0.01)
        assert victim, "no render showed up on an actor"
        os.kill(victim, signal.SIGKILL)
        t.join(120)
        r = out["r"]
        assert r.status_code == 500 and "died" in r.json()["detail"] and str(victim) in r.json()["detail"]
        r = srv.client.get(f"/assets/{duck['id']}/thumbnail", params={"size": 64, "yaw": 41})
        assert r.status_code == 200
        workers = srv.client.get("/readyz").json()["workers"]
        assert sum(w["restarts"] for w in workers) == 1 and victim not in [w["pid"] for w in workers]
    finally:
        srv.stop()
