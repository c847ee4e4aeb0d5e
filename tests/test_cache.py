"""The content-addressed bake cache: hits, invalidation, corruption, races, eviction."""
from __future__ import annotations

import json
import logging
import multiprocessing as mp
import shutil
from pathlib import Path

import numpy as np
import pytest

from core.errors import AssetError
from pipeline.bake import bake_asset, bake_or_load_asset, load_baked
from pipeline.cache import Cache, CorruptEntry, NotInCache, parse_size
from pipeline.ingest import load_scene


def _copy(src: Path, dst_dir: Path) -> Path:
    dst_dir.mkdir(parents=True, exist_ok=True)
    dst = dst_dir / src.name
    shutil.copyfile(src, dst)  # not copy(): the shared assets are read-only
    return dst


def test_second_bake_is_a_hit_with_equal_data(assets, tmp_path):
    src = _copy(assets / "gltf" / "Duck.glb", tmp_path / "src")
    first, hit1 = bake_or_load_asset(src, tmp_path / "cache")
    second, hit2 = bake_or_load_asset(src, tmp_path / "cache")
    assert (hit1, hit2) == (False, True)
    assert first.key == second.key and len(first.key) == 64
    for a, b in zip(first.meshes, second.meshes):
        np.testing.assert_array_equal(a.positions, b.positions)
        np.testing.assert_array_equal(a.indices, b.indices)
        np.testing.assert_array_equal(a.transforms, b.transforms)
        assert a.material == b.material
    manifest = json.loads((tmp_path / "cache" / "assets" / first.key / "manifest.json").read_text())
    assert manifest["inputs"][0]["sha256"] and manifest["versions"]["bake_format"] >= 1
    assert all(len(f["sha256"]) == 64 for f in manifest["files"].values())
    # --force bakes again and swaps the new entry in
    manifest_file = tmp_path / "cache" / "assets" / first.key / "manifest.json"
    inode = manifest_file.stat().st_ino
    forced, hit3 = bake_or_load_asset(src, tmp_path / "cache", force=True)
    assert not hit3 and forced.key == first.key and manifest_file.stat().st_ino != inode
    # same bytes elsewhere: same key, and found without baking
    other = _copy(src, tmp_path / "elsewhere")
    assert bake_or_load_asset(other, tmp_path / "cache")[0].key == first.key


def test_hit_loads_without_the_source(assets, tmp_path):
    src = _copy(assets / "gltf" / "BoxTextured.glb", tmp_path / "src")
    scene = load_scene(src)
    baked = bake_asset(src, tmp_path / "cache")
    src.unlink()
    again = load_baked(baked.key, tmp_path / "cache")
    assert again.meshes[0].material == scene.materials[scene.instances[0].material]
    np.testing.assert_array_equal(again.textures[0].mips(True)[0], scene.textures[0].image)  # under the cap: as decoded
    np.testing.assert_allclose(again.bounds, scene.bounds)
    with pytest.raises(AssetError):
        bake_asset(src, tmp_path / "cache")  # the file is gone: a clean error, not a crash


def test_changed_dependency_is_a_new_key(assets, tmp_path):
    gltf = _copy(assets / "gltf" / "TestScene.gltf", tmp_path / "src")
    bin_ = _copy(assets / "gltf" / "TestScene.bin", tmp_path / "src")
    first, _ = bake_or_load_asset(gltf, tmp_path / "cache")
    data = bytearray(bin_.read_bytes())
    data[100] ^= 0x01  # a low mantissa bit of some vertex attribute: still a valid asset
    bin_.write_bytes(bytes(data))
    second, hit = bake_or_load_asset(gltf, tmp_path / "cache")
    assert not hit and second.key != first.key
    assert any(i["path"] == "TestScene.bin" for i in second.manifest["inputs"])


def test_corrupted_file_is_detected_and_rebaked(assets, tmp_path, caplog):
    src = _copy(assets / "gltf" / "Duck.glb", tmp_path / "src")
    cache = tmp_path / "cache"
    key = bake_asset(src, cache).key
    target = cache / "assets" / key / "meshes.npz"
    data = bytearray(target.read_bytes())
    data[len(data) // 2] ^= 0xFF
    target.write_bytes(bytes(data))
    with caplog.at_level(logging.WARNING, logger="pipeline.cache"):
        again, hit = bake_or_load_asset(src, cache)
    assert not hit and again.key == key
    assert "checksum mismatch" in caplog.text
    assert bake_or_load_asset(src, cache)[1]  # the rebaked entry is whole again
    (cache / "assets" / key / "meshes.npz").unlink()  # a partial entry: rebaked too
    assert not bake_or_load_asset(src, cache)[1]
    with pytest.raises(NotInCache):
        load_baked("0" * 64, cache)
    with pytest.raises(NotInCache):
        load_baked("../../etc/passwd", cache)


def test_corrupted_texture_is_never_used(assets, tmp_path):
    src = _copy(assets / "gltf" / "BoxTextured.glb", tmp_path / "src")
    cache = tmp_path / "cache"
    key = bake_asset(src, cache).key
    tex = cache / "assets" / key / "texture.0.srgb.zst"
    data = bytearray(tex.read_bytes())
    data[-10] ^= 0xFF
    tex.write_bytes(bytes(data))
    with pytest.raises(CorruptEntry):
        load_baked(key, cache).textures[0].mips(True)  # read lazily, checksummed on first use
    assert not (cache / "assets" / key).exists()
    assert not bake_or_load_asset(src, cache)[1]


def _bake_in_child(path, cache, barrier, queue):
    barrier.wait()
    try:
        queue.put(bake_asset(path, cache).key)
    except Exception as exc:  # reported to the parent, which fails the test
        queue.put(f"error: {exc!r}")


@pytest.mark.slow
def test_concurrent_bakes_from_two_processes(assets, tmp_path):
    src = _copy(assets / "gltf" / "CesiumMilkTruck.glb", tmp_path / "src")
    cache = tmp_path / "cache"
    ctx = mp.get_context("spawn")
    barrier, queue = ctx.Barrier(2), ctx.Queue()
    procs = [ctx.Process(target=_bake_in_child, args=(str(src), str(cache), barrier, queue))
             for _ in range(2)]
    for p in procs:
        p.start()
    keys = [queue.get(timeout=120) for _ in procs]
    for p in procs:
        p.join(timeout=30)
        assert p.exitcode == 0
    assert keys[0] == keys[1] and len(keys[0]) == 64, keys
    assert list((cache / "tmp").iterdir()) == []  # the loser discarded its copy
    again, hit = bake_or_load_asset(src, cache)
    assert hit and again.key == keys[0]
    assert again.textures[0].mips(True)[0].shape[2] == 4  # whole, checksums included


def test_race_loser_discards_its_copy(tmp_path, caplog):
    cache = Cache(tmp_path)
    key = "ab" * 32
    first = cache.store("assets", key, {"who": "first"}, {"a.npz": {"x": np.arange(3)}})
    with caplog.at_level(logging.INFO, logger="pipeline.cache"):
        cache.store("assets", key, {"who": "second"}, {"a.npz": {"x": np.arange(3)}})
    assert "stored concurrently" in caplog.text
    entry = cache.load("assets", key)
    assert entry.manifest["who"] == "first" and first.path == entry.path
    np.testing.assert_array_equal(entry.arrays["a.npz"]["x"], np.arange(3))
    assert list((tmp_path / "tmp").iterdir()) == []


def test_transmissive_asset_round_trip_keeps_interior(tmp_path):
    from bench.scenes import scene, write_glb
    path = write_glb(scene("glass_ellipsoid_311_ior1.5"), tmp_path / "glass.glb")
    baked = bake_asset(path, tmp_path / "cache")
    path.unlink()
    again = load_baked(baked.key, tmp_path / "cache")
    (mesh,) = again.meshes
    assert mesh.material.material_class == "transmissive" and mesh.material.ior == pytest.approx(1.5)
    assert mesh.interior.shape == mesh.positions.shape and np.all(np.isfinite(mesh.interior))
    np.testing.assert_allclose(np.median(mesh.interior_length), 2.0, rtol=0.01)  # object space
    assert again.manifest["stats"]["interior"]["rays"] >= len(mesh.positions)


def test_size_cap_evicts_least_recently_used(assets, tmp_path):
    cache_dir = tmp_path / "cache"
    srcs = [_copy(assets / "mesh" / name, tmp_path / "src") for name in
            ("torus.STL", "suzanne.ply", "bunny.ply")]
    keys = [bake_asset(s, cache_dir).key for s in srcs]
    load_baked(keys[0], cache_dir)  # touch the first: the second is now least recent
    total = sum(e[1] for e in Cache(cache_dir).entries())
    freed = Cache(cache_dir, max_bytes=total - 1).evict()
    left = {e[3] for e in Cache(cache_dir).entries()}
    assert left == {keys[0], keys[2]} and freed > 0
    # a store under a cap evicts too, never the entry it just wrote
    tiny = Cache(cache_dir, max_bytes=1)
    assert bake_asset(srcs[1], tiny).key == keys[1]
    assert {e[3] for e in Cache(cache_dir).entries()} == {keys[1]}
    assert parse_size("2G") == 2 * 2**30 and parse_size("0") is None


def test_environment_bake_hit_and_load_by_key(tmp_path):
    from pipeline.bake import bake_environment, bake_or_load_environment, load_environment
    env, hit = bake_or_load_environment("neutral", tmp_path, face_size=32)
    assert not hit and env.face_size == 32 and env.prefilter == "ggx"
    assert [m.shape for m in env.specular][:2] == [(6, 32, 32, 3), (6, 16, 16, 3)]
    assert env.irradiance_sh.shape == (9, 3) and env.brdf_lut.shape[2] == 3
    assert all(np.all(np.isfinite(m)) for m in env.specular)
    again = bake_environment("neutral", tmp_path, face_size=32)
    assert again.key == env.key
    by_key = load_environment(env.key, tmp_path)
    for a, b in zip(env.specular, by_key.specular):
        np.testing.assert_array_equal(a, b)
    assert bake_environment("neutral", tmp_path, face_size=32, prefilter="paper").key != env.key
    with pytest.raises(AssetError):
        bake_environment(str(tmp_path / "nope.hdr"), tmp_path)
