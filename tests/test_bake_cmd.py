"""`asset-bake`: result lines, exit codes, second run all cached, parallel workers."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from cli import bake as bake_cmd


@pytest.fixture
def library(assets, tmp_path) -> Path:
    lib = tmp_path / "lib"
    (lib / "sub").mkdir(parents=True)
    shutil.copyfile(assets / "gltf" / "Duck.glb", lib / "Duck.glb")
    shutil.copyfile(assets / "mesh" / "torus.STL", lib / "sub" / "torus.STL")
    (lib / "notes.txt").write_text("not an asset")  # ignored when walking
    return lib


def _json_lines(text: str) -> dict[str, dict]:
    rows = [json.loads(line) for line in text.splitlines() if line.strip()]
    return {Path(r["path"]).name: r for r in rows}


def test_walks_folders_and_second_run_is_all_cached(library, tmp_path, capsys):
    cache = str(tmp_path / "cache")
    assert bake_cmd.main([str(library), "--cache", cache]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 2 and all(line.startswith("baked ") for line in out)
    entries = sorted(p.name for p in (tmp_path / "cache" / "assets").iterdir())
    assert bake_cmd.main([str(library), "--cache", cache, "--json"]) == 0
    rows = _json_lines(capsys.readouterr().out)
    assert set(rows) == {"Duck.glb", "torus.STL"}
    assert {r["status"] for r in rows.values()} == {"cached"}
    assert sorted(p.name for p in (tmp_path / "cache" / "assets").iterdir()) == entries
    assert bake_cmd.main([str(library), "--cache", cache, "--force", "--json"]) == 0
    assert {r["status"] for r in _json_lines(capsys.readouterr().out).values()} == {"baked"}


def test_failures_exit_3_and_the_rest_still_bakes(library, tmp_path, capsys):
    (library / "broken.glb").write_bytes(b"glTF\x02\x00\x00\x00" + b"\x00" * 8)
    missing = library / "missing.gltf"
    code = bake_cmd.main([str(library), str(missing), "--cache", str(tmp_path / "cache"), "--json"])
    assert code == 3
    rows = _json_lines(capsys.readouterr().out)
    assert rows["Duck.glb"]["status"] == rows["torus.STL"]["status"] == "baked"
    for name in ("broken.glb", "missing.gltf"):
        assert rows[name]["status"] == "failed" and name in rows[name]["error"]
    code = bake_cmd.main([str(library / "broken.glb"), "--cache", str(tmp_path / "cache")])
    assert code == 3 and capsys.readouterr().out.startswith("failed: ")
    assert bake_cmd.main(["--cache", str(tmp_path / "cache")]) == 2  # nothing to do


def test_environment_and_asset_preview_bake_alias(tmp_path, capsys):
    from cli.main import main as asset_preview
    args = ["bake", "--env", "neutral", "--face-size", "32", "--prefilter", "paper",
            "--cache", str(tmp_path / "cache"), "--json"]
    assert asset_preview(args) == 0
    first = json.loads(capsys.readouterr().out)
    assert first["status"] == "baked" and first["kind"] == "environment" and first["face_size"] == 32
    assert asset_preview(args) == 0
    assert json.loads(capsys.readouterr().out)["status"] == "cached"


@pytest.mark.slow
def test_workers_bake_in_parallel_processes(library, tmp_path):
    for i in range(2):
        shutil.copyfile(library / "Duck.glb", library / f"copy{i}.glb")  # same bytes: one key
    proc = subprocess.run([sys.executable, "-m", "cli.bake", str(library), "--workers", "2",
                           "--cache", str(tmp_path / "cache"), "--json"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    rows = _json_lines(proc.stdout)
    assert set(rows) == {"Duck.glb", "copy0.glb", "copy1.glb", "torus.STL"}
    assert len({rows[n]["key"] for n in ("Duck.glb", "copy0.glb", "copy1.glb")}) == 1
    assert "0 failed" in proc.stderr
    assert len(list((tmp_path / "cache" / "assets").iterdir())) == 2
