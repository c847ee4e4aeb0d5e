"""model:drawMode as usdview draws it (pipeline/usd/drawmode.py): origin / bounds / cards
stand-ins in place of the models they apply to (applyDrawMode, or kind component without
one), the mode resolved up the model hierarchy; draw_mode=full draws the geometry; the
option reaches the bake key, the CLI and the HTTP query."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from core.options import from_request
from pipeline.bake import bake_or_load_asset
from pipeline.ingest import load_scene

STAGE = """#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
)
def Xform "World" (
    kind = "group"
)
{
    def Xform "Axes" ( prepend apiSchemas = ["GeomModelAPI"]
        kind = "component" )
    {
        uniform token model:drawMode = "origin"
        float3 model:drawModeColor = (0, 1, 0)
        double3 xformOp:translate = (10, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
        def Cube "Body" {
            double size = 2
        }
    }
    def Xform "Box" ( prepend apiSchemas = ["GeomModelAPI"]
        kind = "component" )
    {
        uniform token model:drawMode = "bounds"
        float3 model:drawModeColor = (1, 0, 0)
        def Cube "Body" {
            double size = 2
        }
    }
    def Xform "Cards" ( prepend apiSchemas = ["GeomModelAPI"]
        kind = "component" )
    {
        uniform token model:drawMode = "cards"
        uniform token model:cardGeometry = "box"
        float3 model:drawModeColor = (0, 0, 1)
        asset model:cardTextureXPos = @./x.png@
        asset model:cardTextureYPos = @./missing.png@
        double3 xformOp:translate = (0, 0, 10)
        uniform token[] xformOpOrder = ["xformOp:translate"]
        def Cube "Body" {
            double size = 2
        }
    }
    def Xform "Refused" ( prepend apiSchemas = ["GeomModelAPI"]
        kind = "component" )
    {
        uniform token model:drawMode = "bounds"
        uniform bool model:applyDrawMode = 0
        double3 xformOp:translate = (-10, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
        def Cube "Body" {
            double size = 2
        }
    }
    def Xform "Group" ( prepend apiSchemas = ["GeomModelAPI"]
        kind = "group" )
    {
        uniform token model:drawMode = "cards"
        double3 xformOp:translate = (0, 0, -10)
        uniform token[] xformOpOrder = ["xformOp:translate"]
        def Xform "Inner" (
            kind = "component"
        )
        {
            def Sphere "Ball" {
                double radius = 1
            }
        }
    }
    def Xform "NotAModel"
    {
        def Xform "Applied" ( prepend apiSchemas = ["GeomModelAPI"] )
        {
            uniform token model:drawMode = "bounds"
            uniform bool model:applyDrawMode = 1
            def Cube "Body" {
            double size = 2
        }
        }
    }
}
"""


@pytest.fixture
def stage(tmp_path) -> Path:
    # x.png: left half red, right half white, so that a mirrored card is told apart
    img = np.full((8, 8, 4), 255, np.uint8)
    img[:, :4, 1:3] = 0
    Image.fromarray(img, "RGBA").save(tmp_path / "x.png")
    path = tmp_path / "drawmode.usda"
    path.write_text(STAGE)
    return path


def _names(scene) -> set[str]:
    return {m.name for m in scene.meshes}


def _material(scene, name: str):
    inst = next(i for i in scene.instances if scene.meshes[i.mesh].name == name)
    return scene.materials[inst.material], inst


def test_stand_ins_replace_the_models_they_apply_to(stage):
    scene = load_scene(stage)
    names = _names(scene)
    # replaced: their geometry is not drawn
    for gone in ("/World/Axes/Body", "/World/Box/Body", "/World/Cards/Body", "/World/Group/Inner/Ball"):
        assert gone not in names
    assert {"/World/Axes:origin", "/World/Box:bounds"} <= names
    # applyDrawMode = 0 on a component: drawn as it is
    assert "/World/Refused/Body" in names
    # inherited: the component under a cards group takes cards (with no texture: 6 quads)
    assert {f"/World/Group/Inner:cards{f}" for f in ("XPos", "XNeg", "YPos", "YNeg", "ZPos", "ZNeg")} <= names
    # a prim that is not a model never takes a stand-in, applyDrawMode or not
    assert "/World/NotAModel/Applied/Body" in names


def test_bounds_and_origin_lines(stage):
    scene = load_scene(stage)
    box = next(m for m in scene.meshes if m.name == "/World/Box:bounds")
    mat, inst = _material(scene, "/World/Box:bounds")
    assert mat.unlit and mat.base_color[:3] == (1.0, 0.0, 0.0)
    p = box.positions @ inst.matrix[:3, :3].T + inst.matrix[:3, 3]
    lo, hi = p.min(axis=0), p.max(axis=0)
    width = float(hi[0] - lo[0]) - 2.0  # the tubes stick out of the 2 m cube by their width
    assert 0 < width < 0.2
    np.testing.assert_allclose(lo, -1 - width / 2, atol=1e-4)
    np.testing.assert_allclose(hi, 1 + width / 2, atol=1e-4)
    # 12 edges of 6 quads each, none through the box's inside
    assert len(box.indices) == 12 * 12
    centre_dist = np.abs(p).max(axis=1)
    assert centre_dist.min() > 1 - width
    axes = next(m for m in scene.meshes if m.name == "/World/Axes:origin")
    mat, inst = _material(scene, "/World/Axes:origin")
    assert mat.base_color[:3] == (0.0, 1.0, 0.0)
    q = axes.positions @ inst.matrix[:3, :3].T + inst.matrix[:3, 3]
    # unit axes from the prim's origin (10, 0, 0), whatever its geometry's size
    np.testing.assert_allclose(q.max(axis=0), (11 + width / 2, 1 + width / 2, 1 + width / 2), atol=1e-4)
    np.testing.assert_allclose(q.min(axis=0), (10 - width / 2, -width / 2, -width / 2), atol=1e-4)


def test_cards_textures_mirroring_and_missing(stage):
    scene = load_scene(stage)
    names = _names(scene)
    cards = {n.rpartition(":cards")[2] for n in names if n.startswith("/World/Cards:cards")}
    # textures on X (one found) and Y (missing): those axes only, both faces of each
    assert cards == {"XPos", "XNeg", "YPos", "YNeg"}
    xpos, inst = _material(scene, "/World/Cards:cardsXPos")
    xneg, _ = _material(scene, "/World/Cards:cardsXNeg")
    assert xpos.base_color_texture is not None and xpos.alpha_mode == "MASK"
    assert xneg.base_color_texture.texture == xpos.base_color_texture.texture
    assert scene.textures[xpos.base_color_texture.texture].source.endswith("x.png")
    # the missing texture: drawModeColor, and a warning naming the file
    ypos, _ = _material(scene, "/World/Cards:cardsYPos")
    assert ypos.base_color_texture is None and ypos.base_color[:3] == (0.0, 0.0, 1.0)
    assert any("missing.png" in w and "drawModeColor" in w for w in scene.warnings)
    # box quads on the faces, facing out; XNeg shows XPos's image seen through: same u at
    # the same world point, so the red half is on the same side of the model
    for face, x in (("XPos", 1.0), ("XNeg", -1.0)):
        mesh = next(m for m in scene.meshes if m.name == f"/World/Cards:cards{face}")
        np.testing.assert_allclose(mesh.positions[:, 0], x)
        np.testing.assert_allclose(mesh.normals, np.tile([x, 0, 0], (4, 1)))
        tri = mesh.positions[mesh.indices[0]]
        assert np.dot(np.cross(tri[1] - tri[0], tri[2] - tri[0]), [x, 0, 0]) > 0
        for p, uv in zip(mesh.positions, mesh.uv0):
            assert uv[0] == pytest.approx((p[1] + 1) / 2)   # s = y on +X
            assert uv[1] == pytest.approx(1 - (p[2] + 1) / 2)  # t = z, v down


def test_teapot_draw_modes_stage(assets):
    """usd-wg's DrawModes stage: 5 columns per teapot, default / cross / box / bounds / origin
    (no applyDrawMode authored: kind component applies them)."""
    scene = load_scene(assets / "usd/Teapot/DrawModes.usd")
    names = _names(scene)
    teapots = 7
    assert sum(n.endswith(":bounds") for n in names) == teapots
    assert sum(n.endswith(":origin") for n in names) == teapots
    assert sum(n.endswith(":cardsXPos") for n in names) == 2 * teapots  # cross and box
    assert sum("/Geometry" in n for n in names) >= 2  # the default column (Utah, Fancy)
    full = load_scene(assets / "usd/Teapot/DrawModes.usd", draw_mode="full")
    assert not any(":cards" in n or ":bounds" in n for n in _names(full))
    assert full.triangle_count > scene.triangle_count


def test_draw_mode_option_reaches_the_bake_key_cli_and_query(stage, tmp_path):
    authored, _ = bake_or_load_asset(stage, tmp_path / "cache")
    full, cached = bake_or_load_asset(stage, tmp_path / "cache", draw_mode="full")
    assert not cached and full.key != authored.key
    assert from_request({"draw_mode": "full"}).draw_mode == "full"
    with pytest.raises(ValueError):
        from_request({"draw_mode": "cards"})
    import argparse

    from core.options import add_arguments, from_arguments
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert from_arguments(parser.parse_args(["--draw-mode", "full"])).draw_mode == "full"
    assert from_arguments(parser.parse_args([])).draw_mode == "authored"


CARDS_ONLY = """#usda 1.0
(
    metersPerUnit = 1
    upAxis = "Y"
)
def Xform "Cards" (
    prepend apiSchemas = ["GeomModelAPI"]
    kind = "component"
)
{
    uniform token model:drawMode = "cards"
    uniform token model:cardGeometry = "box"
    asset model:cardTextureXPos = @./x.png@
    def Cube "Body"
    {
        double size = 2
    }
}
"""


@pytest.mark.parametrize("yaw", [90.0, -90.0])
def test_cards_render_their_texture_from_both_sides(tmp_path, yaw):
    """Rendered: seen from +X the XPos card shows x.png (its s runs up +Y, so the red half is
    below); from -X the XNeg card shows the same image seen through, red below too."""
    from test_render_physics import constant_env

    from core.options import RenderOptions
    from pipeline.bake import bake_asset
    from renderer.raster.render import render
    img = np.full((8, 8, 4), 255, np.uint8)
    img[:, :4, 1:3] = 0  # s < 0.5 red
    Image.fromarray(img, "RGBA").save(tmp_path / "x.png")
    (tmp_path / "cards.usda").write_text(CARDS_ONLY)
    asset = bake_asset(tmp_path / "cards.usda", tmp_path / "cache")
    opts = RenderOptions(width=64, height=64, yaw=yaw, pitch=0, tonemap="none",
                         background="transparent", msaa=0, shadow=0)
    frame = render(asset, constant_env(1.0), opts).linear
    covered = frame[..., 3] > 0.5
    assert covered.mean() > 0.3
    rows = np.where(covered.any(axis=1))[0]
    mid = (rows.min() + rows.max()) // 2
    upper = frame[rows.min():mid - 2][covered[rows.min():mid - 2]][:, :3].mean(axis=0)
    lower = frame[mid + 3:rows.max() + 1][covered[mid + 3:rows.max() + 1]][:, :3].mean(axis=0)
    assert lower[0] > 4 * max(lower[1], lower[2])  # red
    assert min(upper) > 0.5 * max(upper)  # white


BOUNDS_ONLY = """#usda 1.0
(
    metersPerUnit = 1
    upAxis = "Y"
)
def Xform "Model" (
    prepend apiSchemas = ["GeomModelAPI"]
    kind = "component"
)
{
    uniform token model:drawMode = "bounds"
    float3 model:drawModeColor = (1, 0, 0)
    def Sphere "Ball"
    {
        double radius = 1
    }
}
"""


def test_draw_mode_over_http(server):
    """The query's draw_mode reaches the worker's bake: the red bounds box by default, the
    sphere itself with draw_mode=full; an unknown value is a 422."""
    from test_service import decode, upload
    r = upload(server, "bounds.usda", BOUNDS_ONLY.encode())
    assert r.status_code in (200, 201), r.text
    rec = server.wait_status(r.json()["id"])
    assert rec["status"] == "ready", rec
    url = f"/assets/{rec['id']}/thumbnail"
    q = {"size": 48, "msaa": 0, "shadow": 0}
    box = server.client.get(url, params=q)
    full = server.client.get(url, params={**q, "draw_mode": "full"})
    assert box.status_code == 200 and full.status_code == 200, full.text
    box_img, full_img = decode(box.content).astype(float), decode(full.content).astype(float)
    red = lambda im: ((im[..., 0] > 150) & (im[..., 1] < 80) & (im[..., 2] < 80)).sum()  # noqa: E731
    assert red(box_img) > 20 and red(full_img) == 0
    assert server.client.get(url, params={**q, "draw_mode": "cards"}).status_code == 422


FROM_TEXTURE = """#usda 1.0
(
    metersPerUnit = 1
    upAxis = "Y"
)
def Xform "Model" (
    prepend apiSchemas = ["GeomModelAPI"]
    kind = "component"
)
{
    uniform token model:drawMode = "cards"
    uniform token model:cardGeometry = "fromTexture"
    asset model:cardTextureZPos = @./zpos.exr@
    asset model:cardTextureXPos = @./xpos.exr@
    asset model:cardTextureYPos = @./ypos.png@
    def Cube "Body"
    {
        double size = 2
    }
}
"""


def _card_image() -> np.ndarray:
    """16 x 16 linear RGBA: top half blue, bottom-left red, bottom-right white."""
    a = np.ones((16, 16, 4), np.float32)
    a[:8, :, :2] = 0.05
    a[8:, :8, 1:3] = 0.05
    return a


def _write_exr(path: Path, world_to_screen: np.ndarray | None, a: np.ndarray) -> None:
    import OpenEXR
    header = {} if world_to_screen is None else {"worldToNDC": world_to_screen.astype(np.float32)}
    OpenEXR.File(header, {c: a[..., i].copy() for i, c in enumerate("RGBA")}).write(str(path))


@pytest.fixture
def from_texture(tmp_path) -> Path:
    # screen = world @ W (row vectors, y down as the image's rows): z = 1 plane seen from +Z
    wz = np.diag([1.0, -1.0, 1.0, 1.0])
    wz[3, 2] = -1.0
    # x = 1 plane seen from +X: screen x = -z, screen y = -y
    wx = np.zeros((4, 4))
    wx[2, 0], wx[1, 1], wx[0, 2], wx[3, 2], wx[3, 3] = -1, -1, 1, -1, 1
    _write_exr(tmp_path / "zpos.exr", wz, _card_image())
    _write_exr(tmp_path / "xpos.exr", wx, _card_image())
    Image.fromarray((_card_image() * 255).astype(np.uint8)).save(tmp_path / "ypos.png")
    (tmp_path / "fromtex.usda").write_text(FROM_TEXTURE)
    return tmp_path / "fromtex.usda"


def test_from_texture_cards_are_placed_by_each_textures_worldtoscreen(from_texture):
    """cardGeometry fromTexture: a quad per texture with a worldtoscreen matrix (EXR
    worldToNDC), at the screen square taken back through its inverse; a PNG has no such
    metadata: no card there and a warning naming it (Storm skips it too). Checked against
    Storm by eye and FLIP 0.034 (bench usd on this stage, docs/usd.md)."""
    scene = load_scene(from_texture)
    names = _names(scene)
    assert {"/Model:cardsZPos", "/Model:cardsXPos"} <= names
    assert not any("YPos" in n or "Neg" in n for n in names if ":cards" in n)
    assert "/Model/Body" not in names
    assert any("ypos.png" in w and "worldtoscreen" in w for w in scene.warnings)
    z = next(m for m in scene.meshes if m.name == "/Model:cardsZPos")
    np.testing.assert_allclose(z.positions, [[1, 1, 1], [-1, 1, 1], [-1, -1, 1], [1, -1, 1]], atol=1e-6)
    np.testing.assert_allclose(z.normals, np.tile([0, 0, 1], (4, 1)), atol=1e-6)
    tri = z.positions[z.indices[0]]
    assert np.dot(np.cross(tri[1] - tri[0], tri[2] - tri[0]), [0, 0, 1]) > 0  # faces +Z
    # st (1,1) at the top right seen from +Z, so the image is upright there (glTF v = 1 - t)
    np.testing.assert_allclose(z.uv0, [[1, 0], [0, 0], [0, 1], [1, 1]])
    x = next(m for m in scene.meshes if m.name == "/Model:cardsXPos")
    np.testing.assert_allclose(x.positions[:, 0], 1.0, atol=1e-6)
    np.testing.assert_allclose(x.normals[0], [1, 0, 0], atol=1e-6)
    mat, _ = _material(scene, "/Model:cardsZPos")
    assert mat.alpha_mode == "MASK"
    assert scene.textures[mat.base_color_texture.texture].source.endswith("zpos.exr")


def test_from_texture_card_renders_upright(from_texture, tmp_path):
    """Seen from +Z the card shows its image upright: blue on top, red bottom left."""
    from test_render_physics import constant_env

    from core.options import RenderOptions
    from pipeline.bake import bake_asset
    from renderer.raster.render import render
    asset = bake_asset(from_texture, tmp_path / "cache")
    opts = RenderOptions(width=64, height=64, yaw=0, pitch=0, tonemap="none",
                         background="transparent", msaa=0, shadow=0)
    frame = render(asset, constant_env(1.0), opts).linear
    covered = frame[..., 3] > 0.5
    rows, cols = np.where(covered.any(axis=1))[0], np.where(covered.any(axis=0))[0]
    r0, r1, c0, c1 = rows.min(), rows.max(), cols.min(), cols.max()
    h, w = r1 - r0, c1 - c0
    top = frame[r0 + h // 8:r0 + 3 * h // 8, c0 + w // 4:c1 - w // 4, :3].reshape(-1, 3).mean(axis=0)
    bottom_left = frame[r1 - 3 * h // 8:r1 - h // 8, c0 + w // 8:c0 + 3 * w // 8, :3].reshape(-1, 3).mean(axis=0)
    bottom_right = frame[r1 - 3 * h // 8:r1 - h // 8, c1 - 3 * w // 8:c1 - w // 8, :3].reshape(-1, 3).mean(axis=0)
    assert top[2] > 4 * max(top[0], top[1])
    assert bottom_left[0] > 4 * max(bottom_left[1], bottom_left[2])
    assert min(bottom_right) > 0.5 * max(bottom_right)


def test_from_texture_without_any_matrix_draws_nothing_there(tmp_path):
    _write_exr(tmp_path / "zpos.exr", None, _card_image())
    (tmp_path / "m.usda").write_text(FROM_TEXTURE.replace('asset model:cardTextureXPos = @./xpos.exr@\n', "")
                                     .replace('asset model:cardTextureYPos = @./ypos.png@\n', "")
                                     + 'def Sphere "Other" {}\n')
    scene = load_scene(tmp_path / "m.usda")
    assert not any(":cards" in m.name for m in scene.meshes)
    assert any("zpos.exr" in w and "worldToNDC" in w for w in scene.warnings)
    assert any("nothing drawn" in w for w in scene.warnings)


CARD_VISIBILITY = """#usda 1.0
(
    metersPerUnit = 1
    upAxis = "%s"
)
def Xform "Group" (
    prepend apiSchemas = ["GeomModelAPI"]
    kind = "group"
)
{
    uniform token model:cardVisibility = "simple"
    def Xform "Simple" (
        prepend apiSchemas = ["GeomModelAPI"]
        kind = "component"
    )
    {
        uniform token model:drawMode = "cards"
        uniform token model:cardGeometry = "box"
        def Cube "Body" {
            double size = 2
        }
    }
    def Xform "Full" (
        prepend apiSchemas = ["GeomModelAPI"]
        kind = "component"
    )
    {
        uniform token model:drawMode = "cards"
        uniform token model:cardVisibility = "full"
        def Cube "Body" {
            double size = 2
        }
    }
}
"""


@pytest.mark.parametrize("up", ["Y", "Z"])
def test_card_visibility_simple_leaves_out_the_up_axis_cards(tmp_path, up):
    """model:cardVisibility (USD 26 UsdGeomModelAPI): `simple` drops the cards in the up-axis
    direction, inherited from an ancestor; `full` (and the fallback) keeps all six."""
    (tmp_path / "v.usda").write_text(CARD_VISIBILITY % up)
    names = _names(load_scene(tmp_path / "v.usda"))
    simple = {n.rpartition(":cards")[2] for n in names if n.startswith("/Group/Simple:cards")}
    full = {n.rpartition(":cards")[2] for n in names if n.startswith("/Group/Full:cards")}
    assert simple == {"XPos", "XNeg", "YPos", "YNeg", "ZPos", "ZNeg"} - {f"{up}Pos", f"{up}Neg"}
    assert len(full) == 6
