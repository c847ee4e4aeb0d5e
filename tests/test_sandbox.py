"""The sandbox root: a file named on the command line reads its neighbours as usdview does,
--sandbox DIR and the service's uploads confine what an asset reads, and the root is named
when a reference leaves it. One rule for USD layers, USD/MaterialX textures and glTF URIs."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from cli import bake as bake_cmd
from cli import inspect as inspect_cmd
from core.errors import UnsafeReference
from pipeline.ingest import load_scene

WHEEL = """#usda 1.0
(
    metersPerUnit = 1
)
def Mesh "Wheel"
{
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
    point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    uniform token subdivisionScheme = "none"
}
"""

CAR = """#usda 1.0
(
    metersPerUnit = 1
    defaultPrim = "Car"
)
def Xform "Car"
{
    def "FrontWheel" ( prepend references = @../../parts/wheel.usda@</Wheel> ) {}
    def "BackWheel" ( prepend references = @../../parts/wheel.usda@</Wheel> )
    {
        double3 xformOp:translate = (3, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
}
"""


@pytest.fixture
def library(tmp_path, assets) -> Path:
    """LIB/cars/car/car.usda references LIB/parts/wheel.usda, as vehicle kits share wheels;
    LIB/gltf/box/box.gltf reads LIB/gltf/common/*.bin the same way."""
    lib = tmp_path / "LIB"
    (lib / "parts").mkdir(parents=True)
    (lib / "parts" / "wheel.usda").write_text(WHEEL)
    (lib / "cars" / "car").mkdir(parents=True)
    (lib / "cars" / "car" / "car.usda").write_text(CAR)
    src = assets / "gltf-samples"
    box = next(p for p in sorted(src.rglob("*.gltf")) if p.stem == "Box")
    doc = json.loads(box.read_text())
    (lib / "gltf" / "box").mkdir(parents=True)
    (lib / "gltf" / "common").mkdir()
    for buf in doc["buffers"]:
        shutil.copyfile(box.parent / buf["uri"], lib / "gltf" / "common" / buf["uri"])
        buf["uri"] = "../common/" + buf["uri"]
    (lib / "gltf" / "box" / "box.gltf").write_text(json.dumps(doc))
    return lib


def _rows(text: str) -> dict[str, dict]:
    return {Path(r["path"]).name: r for r in map(json.loads, text.splitlines())}


def test_library_folder_bakes_with_shared_parts(library, tmp_path, capsys):
    code = bake_cmd.main([str(library), "--cache", str(tmp_path / "cache"), "--json"])
    rows = _rows(capsys.readouterr().out)
    assert code == 0, rows
    assert rows["car.usda"]["status"] == "baked" and rows["car.usda"]["triangles"] == 2
    assert rows["box.gltf"]["status"] == "baked" and rows["box.gltf"]["triangles"] == 12


def test_single_file_reads_its_neighbours_and_sandbox_confines(library, tmp_path, capsys):
    """A file named on the command line reads its neighbours as usdview does; --sandbox DIR
    confines it to DIR, naming DIR when a reference leaves it."""
    cache = str(tmp_path / "cache")
    for asset in (library / "cars/car/car.usda", library / "gltf/box/box.gltf"):
        assert bake_cmd.main([str(asset), "--cache", cache]) == 0
        capsys.readouterr()
        # a bake made unconfined is not handed to a confined call from the cache
        assert bake_cmd.main([str(asset), "--cache", cache, "--json",
                              "--sandbox", str(asset.parent)]) == bake_cmd.EXIT_FAILED
        row = _rows(capsys.readouterr().out)[asset.name]
        assert row["status"] == "failed"
        assert f"leaves the root {asset.parent.resolve()}" in row["error"], row["error"]
        assert bake_cmd.main([str(asset), "--cache", cache, "--sandbox", str(library)]) == 0
        capsys.readouterr()


def test_sandbox_must_hold_the_asset_and_inspect_takes_it(library, tmp_path, capsys):
    car = library / "cars/car/car.usda"
    with pytest.raises(UnsafeReference, match="outside the root"):
        load_scene(car, root=library / "parts")
    assert load_scene(car, root=library).triangle_count == 2
    with pytest.raises(UnsafeReference, match="leaves the root"):
        load_scene(car)  # the library call's default is the asset's own folder
    parser = __import__("argparse").ArgumentParser()
    inspect_cmd.configure(parser)
    for argv in ([str(car), "--sandbox", str(library), "--json"], [str(car), "--json"]):
        assert inspect_cmd.run(parser.parse_args(argv)) == 0
        assert json.loads(capsys.readouterr().out)["triangles"] == 2
    with pytest.raises(UnsafeReference, match="leaves the root"):
        inspect_cmd.run(parser.parse_args([str(car), "--sandbox", str(car.parent)]))


def test_absolute_reference_reads_on_the_cli_only(library, server, capsys):
    """An absolute path to a local part is a trusted file's right (usdview follows it); under
    --sandbox and in an upload it is refused, and a URL is refused everywhere."""
    wheel = (library / "parts" / "wheel.usda").resolve()
    car = library / "abs.usda"
    car.write_text(CAR.replace("../../parts/wheel.usda", str(wheel)))
    parser = __import__("argparse").ArgumentParser()
    inspect_cmd.configure(parser)
    assert inspect_cmd.run(parser.parse_args([str(car), "--json"])) == 0
    assert json.loads(capsys.readouterr().out)["triangles"] == 2
    with pytest.raises(UnsafeReference, match="absolute path"):
        inspect_cmd.run(parser.parse_args([str(car), "--sandbox", str(library)]))
    url = library / "url.usda"
    url.write_text(CAR.replace("../../parts/wheel.usda", "https://127.0.0.1:9/wheel.usda"))
    with pytest.raises(UnsafeReference, match="URIs are not followed"):
        inspect_cmd.run(parser.parse_args([str(url)]))
    r = server.client.post("/assets", files={"file": ("abs.usda", car.read_bytes())}, timeout=120)
    assert r.status_code == 422 and "absolute path" in r.json()["detail"], r.text


def test_uploaded_zip_refuses_a_reference_leaving_it(server):
    """The service's root is the upload: a zipped car whose wheel lies outside the zip (on the
    session's shared server: the refusal needs no settings of its own)."""
    import io
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("car/car.usda", CAR)  # ../../parts is outside what the zip holds
    r = server.client.post("/assets", files={"file": ("car.zip", buf.getvalue())}, timeout=120)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]  # spoken of the upload, not of the CLI's --sandbox (issue 29)
    assert "leaves the upload" in detail and "wheel.usda" in detail and "--sandbox" not in detail


def test_uploaded_zip_shares_parts_anywhere_inside_it(server):
    """The service's root is the whole zip: a car in kit/cars/ may use the kit's parts/ (a
    library as uploaded), the part is kept when unreferenced members are dropped, and it bakes
    (on the session's shared server)."""
    import io
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("kit/cars/car.usda", CAR)  # ../../parts/wheel.usda from kit/cars/ is parts/
        zf.writestr("parts/wheel.usda", WHEEL)
        zf.writestr("README.txt", "not referenced: dropped")
    r = server.client.post("/assets", files={"file": ("kit.zip", buf.getvalue())},
                           data={"main": "kit/cars/car.usda"}, timeout=120)
    assert r.status_code == 201, r.text
    asset = r.json()
    assert asset["triangles"] == 2
    asset = server.wait_status(asset["id"])  # the bake runs in the background
    assert asset["status"] == "ready", asset
