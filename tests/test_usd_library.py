"""`asset-bake KIT/`: a USD file another one references is a part, a layer with nothing to
draw (a kit's material library) is skipped with a note; neither is a failure."""
from __future__ import annotations

import json

from cli.bake import main

CAR = """#usda 1.0
(
    defaultPrim = "Car"
    metersPerUnit = 1
)
def Xform "Car" ( prepend references = @./parts/wheel.usda@ )
{
    def Cube "Body"
    {
    }
}
"""
WHEEL = """#usda 1.0
(
    defaultPrim = "Wheel"
)
def Xform "Wheel"
{
    def Cylinder "Tyre"
    {
    }
}
"""
LOOKS = """#usda 1.0
def Material "Paint"
{
}
"""


def test_a_kit_bakes_its_entry_points(tmp_path, capsys):
    kit = tmp_path / "kit"
    (kit / "parts").mkdir(parents=True)
    (kit / "car.usda").write_text(CAR)
    (kit / "parts" / "wheel.usda").write_text(WHEEL)
    (kit / "looks.usda").write_text(LOOKS)
    assert main([str(kit), "--json", "--cache", str(tmp_path / "cache"), "--workers", "1"]) == 0
    lines = {json.loads(line)["path"]: json.loads(line) for line in capsys.readouterr().out.splitlines()}
    assert lines[str(kit / "car.usda")]["status"] == "baked"
    wheel = lines[str(kit / "parts" / "wheel.usda")]
    assert wheel["status"] == "skipped" and "car.usda" in wheel["note"]
    looks = lines[str(kit / "looks.usda")]
    assert looks["status"] == "skipped" and "not an asset" in looks["note"]

    # named on its own, a layer with nothing to draw is still a failure
    assert main([str(kit / "looks.usda"), "--cache", str(tmp_path / "cache")]) == 3


def _zip(members: dict[str, str]) -> bytes:
    import io
    import zipfile
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, text in members.items():
            zf.writestr(name, text)
    return buf.getvalue()


def test_find_root_leaves_out_parts_and_names_the_candidates():
    import pytest

    from service import archive
    files = ["car.usda", "truck.usda", "looks.usda", "parts/wheel.usda"]
    with pytest.raises(archive.AmbiguousEntry) as err:
        archive.find_root(files, "kit.zip")
    assert err.value.candidates == ("car.usda", "looks.usda", "truck.usda")
    assert archive.find_root(files, "kit.zip", parts={"looks.usda", "truck.usda"}) == "car.usda"
    assert archive.usd_layers(files + ["tex/a.png"]) == files


def test_uploaded_kit_zip_takes_its_entry_point_by_the_asset_bake_rule(server):
    """A zipped kit (a car, its wheel part, a material library) is accepted without `main`:
    the part and the drawless layer are not entry points; two cars are refused naming both."""
    r = server.client.post("/assets", files={"file": ("kit.zip", _zip({
        "car.usda": CAR, "parts/wheel.usda": WHEEL, "looks.usda": LOOKS}))}, timeout=120)
    assert r.status_code == 201, r.text
    assert r.json()["triangles"] > 0
    assert server.wait_status(r.json()["id"])["status"] == "ready"
    r = server.client.post("/assets", files={"file": ("two.zip", _zip({
        "car.usda": CAR, "van.usda": CAR.replace('"Body"', '"Van"'), "parts/wheel.usda": WHEEL,
        "looks.usda": LOOKS}))}, timeout=120)
    assert r.status_code == 422, r.text
    assert r.json()["candidates"] == ["car.usda", "van.usda"], r.json()
    assert "main" in r.json()["detail"]
