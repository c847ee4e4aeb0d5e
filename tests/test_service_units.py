"""Service pieces without a server: archive extraction, settings precedence, ids."""
from __future__ import annotations

import io
import struct
import zipfile

import pytest

from core.errors import LimitExceeded, MalformedAsset, UnsafeReference
from service import archive
from service.settings import Settings
from service.store import safe_name
from service.thumbnails import ThumbnailCache
from service.workers.protocol import RenderPlan


def make_zip(path, files: dict[str, bytes]):
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in files.items():
            zf.writestr(name, data)
    return path


def test_extract_writes_only_inside_and_finds_the_root(tmp_path):
    z = make_zip(tmp_path / "Scene.zip", {"Scene/scene.gltf": b"{}", "Scene/scene.bin": b"1",
                                          "Scene/tex/a.png": b"2", "./Scene/./b.txt": b"3"})
    files = archive.extract(z, tmp_path / "out", max_bytes=100, max_files=10)
    assert sorted(files) == ["Scene/b.txt", "Scene/scene.bin", "Scene/scene.gltf", "Scene/tex/a.png"]
    assert (tmp_path / "out/Scene/tex/a.png").read_bytes() == b"2"
    assert archive.find_root(files, "Scene.zip") == "Scene/scene.gltf"


@pytest.mark.parametrize("name, error", [("../x.gltf", UnsafeReference), ("a/../../x.gltf", UnsafeReference),
                                         ("/abs.gltf", UnsafeReference), ("C:/win.gltf", UnsafeReference),
                                         ("..\\x.gltf", UnsafeReference)])
def test_extract_refuses_escapes(tmp_path, name, error):
    z = make_zip(tmp_path / "bad.zip", {"ok.gltf": b"{}", name: b"x"})
    with pytest.raises(error, match="bad.zip"):
        archive.extract(z, tmp_path / "out", max_bytes=100, max_files=10)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*"))
    assert not (tmp_path / "x.gltf").exists()


def test_extract_refuses_links_counts_and_sizes(tmp_path):
    z = tmp_path / "link.zip"
    with zipfile.ZipFile(z, "w") as zf:
        info = zipfile.ZipInfo("evil")
        info.external_attr = 0o120777 << 16
        zf.writestr(info, "/etc/passwd")
    with pytest.raises(UnsafeReference, match="link"):
        archive.extract(z, tmp_path / "o1", max_bytes=100, max_files=10)
    z = make_zip(tmp_path / "many.zip", {f"{i}.bin": b"" for i in range(11)})
    with pytest.raises(LimitExceeded, match="11 files"):
        archive.extract(z, tmp_path / "o2", max_bytes=100, max_files=10)
    z = make_zip(tmp_path / "big.zip", {"a.bin": b"\0" * 101})
    with pytest.raises(LimitExceeded, match="100 bytes"):
        archive.extract(z, tmp_path / "o3", max_bytes=100, max_files=10)


def test_extract_bounds_inflation_when_the_declared_size_lies(tmp_path):
    """A central directory claiming 10 bytes for a 1 MB member: never 1 MB on disk."""
    data = bytearray(make_zip(io.BytesIO(), {"a.bin": b"\0" * 2**20}).getvalue())
    cd = data.rindex(b"PK\x01\x02")
    struct.pack_into("<I", data, cd + 24, 10)  # uncompressed size in the central directory
    z = tmp_path / "liar.zip"
    z.write_bytes(bytes(data))
    with pytest.raises((LimitExceeded, MalformedAsset)):
        archive.extract(z, tmp_path / "out", max_bytes=1000, max_files=10)
    out = tmp_path / "out" / "a.bin"
    assert not out.exists() or out.stat().st_size <= 1000


def test_find_root_needs_a_single_candidate_or_main():
    files = ["a.usda", "b.usda", "tex/c.png"]
    with pytest.raises(MalformedAsset, match="several"):
        archive.find_root(files, "pack.zip")
    assert archive.find_root(files, "b.zip") == "b.usda"
    assert archive.find_root(files, "pack.zip", main="a.usda") == "a.usda"
    with pytest.raises(MalformedAsset, match="not in the archive"):
        archive.find_root(files, "pack.zip", main="z.usda")
    with pytest.raises(MalformedAsset, match="no .gltf"):
        archive.find_root(["readme.txt"], "pack.zip")


def test_settings_flags_over_environment_over_defaults(monkeypatch):
    assert Settings.from_env().max_thumbnail_size == 2048
    monkeypatch.setenv("ASSET_PREVIEW_MAX_THUMBNAIL_SIZE", "1024")
    monkeypatch.setenv("ASSET_PREVIEW_RENDER_WORKERS", "3")
    monkeypatch.setenv("ASSET_PREVIEW_BAKE_WORKERS", "5")
    monkeypatch.setenv("ASSET_PREVIEW_SEED", "false")
    s = Settings.from_env(render_workers=None, cache="/tmp/x")
    assert (s.max_thumbnail_size, s.render_workers, s.seed, str(s.cache)) == (1024, 3, False, "/tmp/x")
    assert Settings.from_env(max_thumbnail_size=512).max_thumbnail_size == 512
    # Render workers of the service and bake processes of asset-bake are distinct knobs.
    from pipeline.limits import PipelineSettings
    assert PipelineSettings().bake_workers == 5
    with pytest.raises(ValueError):  # a malformed value is refused, not silently defaulted
        Settings.from_env(max_queue=0)


def test_safe_names_and_thumbnail_cache(tmp_path):
    assert safe_name("../../etc/passwd") == "passwd"
    assert safe_name("C:\\dir\\My Duck.glb") == "My_Duck.glb"
    assert safe_name(".hidden") == "hidden" and safe_name("") == "upload"
    cache = ThumbnailCache(tmp_path, memory_bytes=1000)
    data, etag, plan = cache.put("a" * 32, "k", "png", b"x" * 100, RenderPlan("raster"))
    assert etag.startswith('"') and cache.get("a" * 32, "k", "png") == (data, etag, plan)
    fresh = ThumbnailCache(tmp_path, memory_bytes=1000)  # as after a restart: from disk
    assert fresh.get("a" * 32, "k", "png") == (data, etag, plan)
    assert list(tmp_path.rglob("*.tmp")) == []


def test_thumbnail_cache_prunes_oldest_first(tmp_path):
    import os
    cache = ThumbnailCache(tmp_path, memory_bytes=0)
    for i in range(10):
        cache.put("a" * 32, f"k{i}", "png", bytes(100), RenderPlan("raster"))
        path = cache.path("a" * 32, f"k{i}", "png")
        os.utime(path, (1000 + i, 1000 + i))
        os.utime(path.with_suffix(".plan.json"), (1000 + i, 1000 + i))
    assert cache.prune(max_bytes=10_000) == 0
    assert cache.prune(max_bytes=800) > 0
    left = sorted(p.name for p in tmp_path.rglob("*.png"))
    assert left and "k9.png" in left and "k0.png" not in left
    assert sum(p.stat().st_size for p in tmp_path.rglob("*") if p.is_file()) <= 720
    assert cache.get("a" * 32, "k0", "png") is None


def test_extract_of_corrupted_archives_raises_only_asset_errors(tmp_path):
    """Random byte flips and truncations of a valid zip: refused as AssetError (-> 422) or
    extracted inside the folder, never another exception (-> 500)."""
    import random

    from core.errors import AssetError
    good = make_zip(io.BytesIO(), {"scene/a.gltf": b'{"asset": {"version": "2.0"}}' * 20,
                                   "scene/tex/b.png": bytes(range(256)) * 8}).getvalue()
    rng = random.Random(16)
    for i in range(300):
        data = bytearray(good)
        for _ in range(rng.randint(1, 6)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        if i % 5 == 0:
            data = data[:rng.randrange(len(data))]
        z = tmp_path / f"{i}.zip"
        z.write_bytes(bytes(data))
        out = tmp_path / f"out{i}"
        try:
            files = archive.extract(z, out, max_bytes=10_000, max_files=10, label="x.zip")
        except AssetError as exc:
            assert str(exc).startswith("x.zip: ") and str(tmp_path) not in str(exc), exc
        else:
            assert all((out / f).resolve().is_relative_to(out.resolve()) for f in files)
