"""A library bake on a Ray cluster of separate `ray start` nodes, all on loopback, that loses a
worker node mid-job: the tasks it held run again elsewhere, every asset is baked exactly once in
the report, and the cache holds only complete entries."""
from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest
import trimesh

from cli import bake as bake_cmd
from pipeline.cache import Cache

ASSETS = 24


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """Distinct meshes (each its own content key): noisy icospheres of ~5k triangles."""
    root = tmp_path_factory.mktemp("lib")
    rng = np.random.default_rng(7)
    for i in range(ASSETS):
        m = trimesh.creation.icosphere(subdivisions=4)
        m.vertices = m.vertices * (1 + 0.05 * rng.standard_normal((len(m.vertices), 1)))
        m.export(root / f"rock{i:02d}.ply")
    return root


def _alive_workers(ray) -> list[dict]:
    return [n for n in ray.nodes() if n["Alive"] and n["Resources"].get("CPU", 0) > 0]


def test_bake_survives_a_lost_worker_node(library, tmp_path, capsys):
    ray = pytest.importorskip("ray")
    from pipeline.executors import LOOPBACK, loopback_cluster

    cache = tmp_path / "cache"
    with loopback_cluster(workers=2) as cluster:
        ray.init(address=cluster.address, _node_ip_address=LOOPBACK, logging_level="WARNING",
                 log_to_driver=False)  # the bake below uses this connection
        try:
            end = time.monotonic() + 120
            while len(_alive_workers(ray)) < 2 and time.monotonic() < end:
                time.sleep(0.5)
            workers = _alive_workers(ray)
            assert len(workers) == 2
            assert {n["NodeManagerAddress"] for n in ray.nodes()} == {LOOPBACK}  # loopback only
            driver = ray.get_runtime_context().get_node_id()
            victim = next(n["NodeManagerPort"] for n in workers if n["NodeID"] != driver)
            killed = {}

            def kill_when_started():
                # once bakes land in the cache (the nodes are working), kill one node outright
                deadline = time.monotonic() + 300
                while time.monotonic() < deadline:
                    done = len(list(cache.glob("assets/*/manifest.json")))
                    if done >= 2:
                        killed["at"] = done
                        cluster.kill_node(victim)
                        return
                    time.sleep(0.05)

            killer = threading.Thread(target=kill_when_started)
            killer.start()
            code = bake_cmd.main([str(library), "--executor", "ray", "--cache", str(cache), "--json"])
            killer.join()
            assert len(_alive_workers(ray)) == 1
        finally:
            ray.shutdown()
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert 2 <= killed.get("at", 0) < ASSETS, killed  # the node died with work left to do
    assert code == 0, [r for r in rows if r["status"] == "failed"]
    paths = [r["path"] for r in rows]
    assert len(paths) == len(set(paths)) == ASSETS  # each asset reported exactly once
    assert {r["status"] for r in rows} == {"baked"}
    store = Cache(cache)
    entries = sorted((cache / "assets").iterdir())
    assert sorted(e.name for e in entries) == sorted({r["key"] for r in rows})
    for entry in entries:  # complete: the manifest and every file it lists, checksums verified
        assert store.load("assets", entry.name) is not None, entry
