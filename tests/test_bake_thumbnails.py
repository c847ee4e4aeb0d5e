"""`asset-bake --thumbnails DIR`: a library's thumbnails in one process (one GL context), the
manifest, and resuming: a re-run renders only what changed."""
from __future__ import annotations

import json
import os
import shutil

import moderngl
import numpy as np
from PIL import Image

from cli import bake as bake_cmd


def _library(assets, root):
    (root / "gltf").mkdir(parents=True)
    (root / "mesh").mkdir()
    shutil.copyfile(assets / "gltf" / "Duck.glb", root / "gltf" / "Duck.glb")
    shutil.copyfile(assets / "gltf" / "BoxTextured.glb", root / "gltf" / "BoxTextured.glb")
    shutil.copyfile(assets / "mesh" / "torus.STL", root / "mesh" / "torus.STL")
    (root / "mesh" / "broken.ply").write_bytes(b"ply\nformat nonsense\n")
    return root


def _run(lib, tmp_path, capsys, *extra):
    code = bake_cmd.main([str(lib), "--cache", str(tmp_path / "cache"), "--thumbnails", str(tmp_path / "th"),
                          "--json", "--size", "64", *extra])
    out = capsys.readouterr().out
    return code, {r["path"]: r for r in map(json.loads, out.splitlines())}


def test_library_thumbnails_manifest_and_resume(assets, tmp_path, capsys, monkeypatch):
    lib = _library(assets, tmp_path / "LIB")
    made = []
    real = moderngl.create_standalone_context
    monkeypatch.setattr(moderngl, "create_standalone_context", lambda *a, **k: made.append(1) or real(*a, **k))
    code, rows = _run(lib, tmp_path, capsys)
    assert code == 3  # the broken file fails; the others are still baked and rendered
    th = tmp_path / "th"
    manifest = json.loads((th / "manifest.json").read_text())["assets"]
    good = {str(lib / "gltf" / "Duck.glb"): "gltf/Duck.glb.png",
            str(lib / "gltf" / "BoxTextured.glb"): "gltf/BoxTextured.glb.png",
            str(lib / "mesh" / "torus.STL"): "mesh/torus.STL.png"}
    for path, name in good.items():
        entry = manifest[path]
        assert entry["status"] == "rendered" and entry["files"] == [name] and entry["key"] == rows[path]["key"]
        assert isinstance(entry["warnings"], list) and entry["seconds"] > 0
        img = np.asarray(Image.open(th / name))
        assert img.shape[:2] == (64, 64) and img.std() > 5  # an object, not a blank frame
    broken = manifest[str(lib / "mesh" / "broken.ply")]
    assert broken["status"] == "failed" and "broken.ply" in broken["error"] and broken["files"] == []
    assert len(made) <= 1  # every thumbnail through this process's one GL context

    # unchanged: nothing rendered again
    stamp = {n: (th / n).stat().st_mtime_ns for n in good.values()}
    code, rows = _run(lib, tmp_path, capsys)
    assert {rows[p]["thumbnail"]["status"] for p in good} == {"kept"}
    assert {n: (th / n).stat().st_mtime_ns for n in good.values()} == stamp

    # a changed asset is rendered again; a deleted thumbnail comes back from the cache, the
    # same bytes, without a render
    torus = (th / "mesh" / "torus.STL.png").read_bytes()
    shutil.copyfile(assets / "gltf" / "CesiumMilkTruck.glb", lib / "gltf" / "Duck.glb")
    (th / "mesh" / "torus.STL.png").unlink()
    code, rows = _run(lib, tmp_path, capsys)
    status = {p: rows[p]["thumbnail"]["status"] for p in good}
    assert status == {str(lib / "gltf" / "Duck.glb"): "rendered", str(lib / "gltf" / "BoxTextured.glb"): "kept",
                      str(lib / "mesh" / "torus.STL"): "cached"}
    assert (th / "mesh" / "torus.STL.png").read_bytes() == torus
    # each render once in the cache, whole: the Duck's old one and new one, and the others
    thumbs = sorted((tmp_path / "cache" / "thumbnails").iterdir())
    assert len(thumbs) == 4
    for entry in thumbs:
        listed = json.loads((entry / "manifest.json").read_bytes())["files"]
        assert {f.name for f in entry.iterdir()} == {"manifest.json", *listed} == {"manifest.json", "thumbnail.png"}
    assert not list(th.rglob("*.tmp*"))

    # the local pool renders in its worker processes, into the same cache: nothing new to render
    code, rows = _run(lib, tmp_path, capsys, "--workers", "2", "--force")
    assert {rows[p]["thumbnail"]["status"] for p in good} == {"kept"}

    # other render options: every thumbnail again, here in two worker processes
    code, rows = _run(lib, tmp_path, capsys, "--yaw", "90", "--workers", "2")
    assert {rows[p]["thumbnail"]["status"] for p in good} == {"rendered"}
    manifest = json.loads((th / "manifest.json").read_text())["assets"]
    assert all(manifest[p]["status"] == "rendered" and (th / manifest[p]["files"][0]).is_file() for p in good)
    assert os.getpid() not in {manifest[p]["by"]["pid"] for p in good}  # rendered where baked: the pool
    assert len(list((tmp_path / "cache" / "thumbnails").iterdir())) == 7


def test_same_file_names_do_not_overwrite(assets, tmp_path, capsys):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    shutil.copyfile(assets / "gltf" / "Duck.glb", tmp_path / "a" / "x.glb")
    shutil.copyfile(assets / "gltf" / "BoxTextured.glb", tmp_path / "b" / "x.glb")
    args = [str(tmp_path / "a" / "x.glb"), str(tmp_path / "b" / "x.glb")]
    code = bake_cmd.main([*args, "--cache", str(tmp_path / "cache"), "--thumbnails", str(tmp_path / "th"),
                          "--json", "--size", "32"])
    assert code == 0, capsys.readouterr().err
    manifest = json.loads((tmp_path / "th" / "manifest.json").read_text())["assets"]
    names = [manifest[p]["files"][0] for p in args]
    assert names[0] == "x.glb.png" and names[1] != names[0] and names[1].startswith("x.glb.")
    first, second = (np.asarray(Image.open(tmp_path / "th" / n)) for n in names)
    assert first.shape == second.shape and not np.array_equal(first, second)  # the duck and the box
    capsys.readouterr()
    # a re-run keeps both names (and both files)
    code = bake_cmd.main([*args, "--cache", str(tmp_path / "cache"), "--thumbnails", str(tmp_path / "th"),
                          "--json", "--size", "32"])
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["thumbnail"]["status"] for r in rows] == ["kept", "kept"]


def test_turntable_thumbnails_and_bad_options(assets, tmp_path, capsys):
    lib = tmp_path / "LIB"
    lib.mkdir()
    shutil.copyfile(assets / "gltf" / "Duck.glb", lib / "Duck.glb")
    code, rows = _run(lib, tmp_path, capsys, "--turntable", "4", "--thumbnail-format", "webp")
    assert code == 0
    with Image.open(tmp_path / "th" / "Duck.glb.webp") as im:
        assert im.n_frames == 4 and im.size == (64, 64)
    for bad, why in ((["--turntable", "4"], "animated webp or gif"), (["--thumbnail-format", "tiff"], "use one of"),
                     (["--size", "0"], "width 0")):
        assert bake_cmd.main([str(lib), "--cache", str(tmp_path / "c2"), "--thumbnails", str(tmp_path / "t2"),
                              *bad]) == 2
        assert why in capsys.readouterr().err
    assert not (tmp_path / "c2").exists()  # refused before any bake
