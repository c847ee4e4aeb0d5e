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
