"""Composition as usdview does it: a missing or unreadable reference is a warning naming the
file (and, where pxr composes it, the prim), and the stage draws what it has; a reference
in a variant left unselected is not needed at all."""
from __future__ import annotations

import pytest

from core.errors import AssetError
from pipeline.ingest import load_scene

CUBE = """#usda 1.0
(
    defaultPrim = "Part"
    metersPerUnit = 1
)
def Xform "Part"
{
    def Cube "Box"
    {
    }
}
"""

STAGE = """#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
)
def Xform "World" (
    variants = { string look = "SELECTED" }
    prepend variantSets = "look"
)
{
    def Sphere "Ball"
    {
    }
    variantSet "look" = {
        "good" {
            def Xform "Extra" ( prepend references = @./part.usda@ ) {}
        }
        "gone" {
            def Xform "Extra" ( prepend references = @./missing.usda@ ) {}
        }
    }
}
"""


def write(tmp_path, selected: str):
    (tmp_path / "part.usda").write_text(CUBE)
    path = tmp_path / "stage.usda"
    path.write_text(STAGE.replace("SELECTED", selected))
    return load_scene(path)


def test_missing_reference_in_an_unselected_variant_loads(tmp_path):
    scene = write(tmp_path, "good")
    assert len(scene.meshes) == 2  # the ball and the referenced cube
    assert not any("missing.usda" in w for w in scene.warnings), scene.warnings


def test_missing_reference_in_the_selected_variant_warns_and_draws_the_rest(tmp_path):
    scene = write(tmp_path, "gone")
    assert len(scene.meshes) == 1  # the ball
    assert any("missing.usda" in w and "Extra" in w for w in scene.warnings), scene.warnings


def test_unreadable_reference_beside_valid_prims(tmp_path):
    (tmp_path / "broken.usda").write_text("#usda 1.0\ndef Cube \"X\" {{{ nonsense\n")
    path = tmp_path / "stage.usda"
    path.write_text(STAGE.replace("SELECTED", "good").replace("missing.usda", "broken.usda")
                    .replace('"good"', '"ok"').replace('= "good"', '= "gone"'))
    path.write_text(path.read_text().replace('string look = "good"', 'string look = "gone"'))
    scene = load_scene(path)
    assert len(scene.meshes) == 1
    assert any("broken.usda" in w for w in scene.warnings), scene.warnings


def test_a_stage_of_nothing_but_missing_references_is_refused(tmp_path):
    path = tmp_path / "empty.usda"
    path.write_text('#usda 1.0\ndef Xform "A" ( prepend references = @./nope.usda@ ) {}\n')
    with pytest.raises(AssetError):
        load_scene(path)
