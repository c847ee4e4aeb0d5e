"""glTF scene features every viewer shows: instancing, skins, morph targets, per-axis wrap
modes, texture transforms on every slot, points and lines, specular-glossiness, material
variants, the asset's cameras, backdrop-aware and not-edge-on framing; and every shared
Khronos sample loads.
"""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder, cube, png_bytes

from cli.inspect import summary
from core.colour import srgb_to_linear
from core.cubemap import default_face_size
from core.errors import AssetError, NotInAsset
from core.options import RenderOptions
from core.scene import CLAMP_TO_EDGE, MIRRORED_REPEAT, NEAREST, REPEAT
from pipeline.bake import bake_asset, bake_environment
from pipeline.environment.panorama import DEFAULT_ENVIRONMENT
from pipeline.ingest import load_scene
from renderer import render
from renderer.view.framing import request_camera

SAMPLES = Path(__file__).resolve().parent / "assets" / "gltf-samples"
ALL_SAMPLES = sorted([*SAMPLES.glob("*/*/*.gltf"), *SAMPLES.glob("*/*/*.glb")])
# Files the README documents as refused, with the reason's text: none at present.
REFUSED: dict[str, str] = {}


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("features-cache")


@pytest.fixture(scope="module")
def env(cache):
    return bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(128))


def _sample(name: str, variant: str = "glTF") -> Path:
    folder = SAMPLES / name / variant
    return next(p for p in folder.iterdir() if p.suffix in (".gltf", ".glb"))


# -- every sample ------------------------------------------------------------------------------

def test_sample_folder_is_found():
    assert len(ALL_SAMPLES) >= 42


@pytest.mark.parametrize("path", ALL_SAMPLES, ids=lambda p: f"{p.parent.parent.name}/{p.parent.name}")
def test_every_sample_loads(path):
    rel = path.relative_to(SAMPLES).as_posix()
    if rel in REFUSED:
        with pytest.raises(AssetError, match=REFUSED[rel]):
            load_scene(path)
        return
    scene = load_scene(path)
    assert scene.triangle_count > 0 and np.isfinite(scene.bounds).all()
    info = summary(scene)
    used = json.loads(json.dumps(info))["extensions"]
    assert set(used.values()) <= {"supported", "partial", "ignored"}
    for name, status in used.items():  # ignored is never silent
        assert status != "ignored" or any(name in w for w in scene.warnings)


# -- instancing ------------------------------------------------------------------------------

def test_simple_instancing_draws_every_instance(cache):
    path = _sample("SimpleInstancing")
    doc = json.loads(path.read_text())
    ext = doc["nodes"][0]["extensions"]["EXT_mesh_gpu_instancing"]
    count = doc["accessors"][ext["attributes"]["TRANSLATION"]]["count"]
    scene = load_scene(path)
    per_mesh = sum(m.triangle_count for m in scene.meshes)
    assert count > 1 and scene.triangle_count == count * per_mesh
    baked = bake_asset(path, cache)
    assert [len(m.transforms) for m in baked.meshes] == [count]  # one instanced draw
    assert baked.triangle_count == scene.triangle_count
    # the instances spread over a grid, not stacked at the origin
    centres = baked.meshes[0].transforms[:, :3, 3]
    assert len(np.unique(centres.round(3), axis=0)) == count


# -- skins -----------------------------------------------------------------------------------

def _skinned(tmp: Path, joint_in_scene: bool = True) -> Path:
    """A static cube at the origin, and a skinned cube bound at the origin whose only joint
    stands at x = +6 (its node's own transform, y = +100, must be ignored). The joint may be
    outside the scene's node tree (skins may name any node)."""
    b = Builder()
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES))
    joints = np.zeros((8, 4), np.uint8)
    weights = np.tile(np.array([1, 0, 0, 0], np.float32), (8, 1))
    mesh = b.mesh(CUBE_POSITIONS, CUBE_INDICES, JOINTS_0=joints, WEIGHTS_0=weights)
    joint = b.node(translation=[6.0, 0.0, 0.0], root=joint_in_scene)
    ibm = np.eye(4, dtype=np.float32).T.reshape(1, 16)  # identity bind pose
    b.doc["accessors"].append({"bufferView": b.view(ibm.tobytes()), "componentType": 5126,
                               "count": 1, "type": "MAT4"})
    b.doc["skins"] = [{"joints": [joint], "inverseBindMatrices": len(b.doc["accessors"]) - 1}]
    b.node(mesh, skin=0, translation=[0.0, 100.0, 0.0])
    return b.write(tmp / "skinned.glb")


def test_skin_joint_outside_the_scene(tmp_path):
    scene = load_scene(_skinned(tmp_path, joint_in_scene=False))
    np.testing.assert_allclose(scene.bounds, [[-1, -1, -1], [7, 1, 1]], atol=1e-5)


def test_skinned_mesh_is_where_its_joints_put_it(tmp_path, cache, env):
    path = _skinned(tmp_path)
    scene = load_scene(path)
    np.testing.assert_allclose(scene.bounds, [[-1, -1, -1], [7, 1, 1]], atol=1e-5)
    baked = bake_asset(path, cache)
    options = RenderOptions(width=128, height=64, yaw=0, pitch=0, background="transparent", msaa=0)
    frame = render(baked, env, options)
    cam = request_camera(baked, options)
    vp = cam.projection_matrix() @ cam.view_matrix()

    def pixel(x):
        clip = vp @ np.array([x, 0.0, 0.0, 1.0])
        ndc = clip[:2] / clip[3]
        return int((1 - ndc[1]) / 2 * options.height), int((ndc[0] + 1) / 2 * options.width)
    alpha = frame.linear[..., 3]
    assert alpha[pixel(6.0)] > 0.5     # the skinned cube, moved by its joint
    assert alpha[pixel(0.0)] > 0.5     # the static one
    assert alpha[pixel(3.5)] == 0.0    # nothing between them
    assert alpha[:, :].sum() > 0 and alpha[: options.height // 4].max() == 0.0  # not at y = 100


@pytest.mark.parametrize("name", ["CesiumMan", "Fox"])
def test_skinned_samples_are_posed(name):
    """Posed by their skins, the characters stand on the ground the right way up and at
    human / fox proportions (unposed, Fox's raw vertices lie in centimetres along Z)."""
    scene = load_scene(_sample(name))
    lo, hi = scene.bounds
    size = hi - lo
    assert size[1] > 0.5 * size.max()            # upright: tall, not lying along Z
    assert abs(lo[1]) < 0.05 * size[1]           # feet on y = 0


# -- morph targets -----------------------------------------------------------------------------

def test_simple_morph_bounds_follow_default_weights():
    path = _sample("SimpleMorph")
    doc = json.loads(path.read_text())
    data = (path.parent / doc["buffers"][0]["uri"]).read_bytes()

    def vec3(acc):
        a = doc["accessors"][acc]
        bv = doc["bufferViews"][a["bufferView"]]
        return np.frombuffer(data, np.float32, a["count"] * 3,
                             bv.get("byteOffset", 0) + a.get("byteOffset", 0)).reshape(-1, 3)
    prim = doc["meshes"][0]["primitives"][0]
    w = doc["meshes"][0]["weights"]
    expected = vec3(prim["attributes"]["POSITION"]) + sum(
        wk * vec3(t["POSITION"]) for wk, t in zip(w, prim["targets"]))
    scene = load_scene(path)
    np.testing.assert_allclose(scene.bounds, [expected.min(axis=0), expected.max(axis=0)], atol=1e-6)
    assert not np.allclose(scene.bounds[1], vec3(prim["attributes"]["POSITION"]).max(axis=0))


def test_node_weights_override_mesh_weights(tmp_path):
    b = Builder()
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    mesh = b.mesh(tri, np.array([0, 1, 2], np.uint16))
    up = b.accessor(np.array([[0, 0, 0], [0, 0, 0], [0, 2, 0]], np.float32))
    b.doc["meshes"][mesh]["primitives"][0]["targets"] = [{"POSITION": up}]
    b.doc["meshes"][mesh]["weights"] = [1.0]
    b.node(mesh, weights=[0.25])
    scene = load_scene(b.write(tmp_path / "m.glb"))
    assert scene.bounds[1][1] == pytest.approx(1.5)


# -- samplers: wrap modes per axis -------------------------------------------------------------

def _wrap(t: np.ndarray, mode: int) -> np.ndarray:
    if mode == CLAMP_TO_EDGE:
        return np.clip(t, 0.0, 1.0)
    if mode == MIRRORED_REPEAT:
        f = np.mod(t, 2.0)
        return np.where(f > 1.0, 2.0 - f, f)
    return np.mod(t, 1.0)


def _expected(image: np.ndarray, uv: np.ndarray, wrap_s: int, wrap_t: int) -> np.ndarray:
    """Nearest-texel lookup of `image` (sRGB RGBA8) at `uv` with glTF's wrap modes, linear."""
    h, w = image.shape[:2]
    s, t = _wrap(uv[..., 0], wrap_s), _wrap(uv[..., 1], wrap_t)
    col = np.clip((s * w).astype(int), 0, w - 1)
    row = np.clip((t * h).astype(int), 0, h - 1)
    return srgb_to_linear(image[row, col, :3])


def _pixel_uvs(baked_mesh, cam, width, height) -> np.ndarray:
    """UV under each pixel centre (NaN off the mesh) for a mesh lying in a plane z = const
    facing the camera: barycentric interpolation in the triangle each pixel ray hits."""
    m = baked_mesh.transforms[0]
    p = baked_mesh.positions.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    assert np.ptp(p[:, 2]) < 1e-5 * np.ptp(p).max()
    d = cam.ray_directions().reshape(-1, 3)
    hit = (cam.position + d * ((p[0, 2] - cam.position[2]) / d[:, 2])[:, None])[:, :2]
    out = np.full((len(hit), 2), np.nan)
    for tri in baked_mesh.indices:
        a, b, c = p[tri, :2]
        t = np.linalg.inv(np.array([b - a, c - a]).T)
        l1, l2 = (t @ (hit - a).T)
        inside = (l1 >= 0) & (l2 >= 0) & (l1 + l2 <= 1)
        uv = baked_mesh.uv0[tri].astype(np.float64)
        out[inside] = ((1 - l1 - l2)[:, None] * uv[0] + l1[:, None] * uv[1]
                       + l2[:, None] * uv[2])[inside]
    return out


@pytest.mark.parametrize("wrap_s,wrap_t", [(MIRRORED_REPEAT, CLAMP_TO_EDGE),
                                           (CLAMP_TO_EDGE, MIRRORED_REPEAT),
                                           (REPEAT, MIRRORED_REPEAT)])
def test_wrap_modes_per_axis_match_numpy(wrap_s, wrap_t, tmp_path, cache, env):
    """An unlit quad with UVs -1..2 and a 4 x 4 texture of distinct colours, sampled NEAREST:
    every pixel away from texel edges shows the texel numpy's wrap arithmetic picks."""
    rng = np.random.default_rng(3)
    image = np.concatenate([rng.integers(0, 256, (4, 4, 3)), np.full((4, 4, 1), 255)], axis=2)
    b = Builder()
    tex = b.image(png_bytes(image.astype(np.uint8)))
    b.doc["samplers"] = [{"magFilter": NEAREST, "minFilter": NEAREST, "wrapS": wrap_s, "wrapT": wrap_t}]
    b.doc["textures"][tex]["sampler"] = 0
    mat = b.material(pbrMetallicRoughness={"baseColorTexture": {"index": tex}},
                     extensions={"KHR_materials_unlit": {}})
    quad = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    uv = np.array([[-1, 2], [2, 2], [2, -1], [-1, -1]], np.float32)  # v down the image
    b.node(b.mesh(quad, np.array([0, 1, 2, 0, 2, 3], np.uint16), material=mat, TEXCOORD_0=uv))
    baked = bake_asset(b.write(tmp_path / "wrap.glb"), cache)
    options = RenderOptions(width=96, height=96, yaw=0, pitch=0, tonemap="none", msaa=0,
                            background="transparent")
    frame = render(baked, env, options)
    cam = request_camera(baked, options)
    uvs = _pixel_uvs(baked.meshes[0], cam, 96, 96)
    got = frame.linear[..., :3].reshape(-1, 3)
    inside = (frame.linear[..., 3].reshape(-1) > 0.99) & np.isfinite(uvs[:, 0])
    # stay a tenth of a texel away from texel edges, where one pixel may land either side
    frac = np.abs(uvs * 4 - np.round(uvs * 4))
    ok = inside & (frac > 0.1).all(axis=1)
    assert ok.sum() > 2000
    want = _expected(image.astype(np.uint8), uvs[ok], wrap_s, wrap_t)
    match = np.abs(got[ok] - want).max(axis=1) < 0.02
    assert match.mean() > 0.98, match.mean()
    wrong = _expected(image.astype(np.uint8), uvs[ok], REPEAT, REPEAT)
    if (wrap_s, wrap_t) != (REPEAT, REPEAT):
        assert (np.abs(got[ok] - wrong).max(axis=1) < 0.02).mean() < 0.8  # the test can fail


def test_texture_settings_sample_keeps_its_wrap_modes(cache):
    """TextureSettingsTest's mirror rows reach the baked textures with MIRRORED_REPEAT on the
    one axis each names (and its clamp rows CLAMP_TO_EDGE)."""
    baked = bake_asset(_sample("TextureSettingsTest"), cache)
    modes = {}
    for m in baked.meshes:
        ref = m.material.base_color_texture
        if ref is not None:
            s = baked.textures[ref.texture].sampler
            modes[m.material.name] = (s.wrap_s, s.wrap_t)
    assert modes["TextureMirrorMaterialS"] == (MIRRORED_REPEAT, REPEAT)
    assert modes["TextureMirrorMaterialT"] == (REPEAT, MIRRORED_REPEAT)
    assert modes["TextureClampMaterialS"] == (CLAMP_TO_EDGE, REPEAT)
    assert modes["TextureClampMaterialT"] == (REPEAT, CLAMP_TO_EDGE)


def test_texture_settings_mirror_cells_match_numpy(cache, env):
    """The sample's own mirror-S cell, drawn alone and unlit head-on, against numpy sampling
    of its texture with the mirrored wrap (LINEAR filtering: compared on the median)."""
    baked = bake_asset(_sample("TextureSettingsTest"), cache)
    for name, wraps in (("TextureMirrorMaterialS", (MIRRORED_REPEAT, REPEAT)),
                        ("TextureMirrorMaterialT", (REPEAT, MIRRORED_REPEAT))):
        mesh = next(m for m in baked.meshes if m.material.name == name)
        mesh = dataclasses.replace(mesh, material=dataclasses.replace(mesh.material, unlit=True,
                                                                     base_color=(1, 1, 1, 1)))
        lo, hi = (mesh.positions.min(axis=0), mesh.positions.max(axis=0))
        lone = dataclasses.replace(baked, key=baked.key + name, meshes=[mesh],
                                   bounds=np.stack([lo, hi]) @ mesh.transforms[0][:3, :3].T
                                   + mesh.transforms[0][:3, 3])
        lone = dataclasses.replace(lone, bounds=np.sort(lone.bounds, axis=0))
        options = RenderOptions(width=128, height=128, yaw=0, pitch=0, tonemap="none", msaa=0,
                                background="transparent")
        frame = render(lone, env, options)
        uvs = _pixel_uvs(mesh, request_camera(lone, options), 128, 128)
        inside = (frame.linear[..., 3].reshape(-1) > 0.99) & np.isfinite(uvs[:, 0])
        image = np.asarray(baked.textures[mesh.material.base_color_texture.texture].image)
        got = frame.linear[..., :3].reshape(-1, 3)[inside]
        err = np.abs(got - _expected(image, uvs[inside], *wraps)).mean(axis=1)
        err_repeat = np.abs(got - _expected(image, uvs[inside], REPEAT, REPEAT)).mean(axis=1)
        assert inside.sum() > 1000
        assert np.median(err) < 0.05 and err.mean() < 0.5 * err_repeat.mean(), (name, err.mean(),
                                                                                err_repeat.mean())


# -- texture transforms, points and lines, specular-glossiness ---------------------------------

def test_texture_transform_on_every_slot(tmp_path):
    b = Builder()
    tex = b.image(png_bytes(np.full((2, 2, 4), 200, np.uint8)))
    tt = {"KHR_texture_transform": {"offset": [0.25, 0.5], "scale": [2, 3], "rotation": 0.5}}
    info = {"index": tex, "extensions": tt}
    mat = b.material(pbrMetallicRoughness={"baseColorTexture": info, "metallicRoughnessTexture": info},
                     normalTexture=info, occlusionTexture=info, emissiveTexture=info,
                     emissiveFactor=[1, 1, 1])
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=mat,
                  TEXCOORD_0=np.zeros((8, 2), np.float32)))
    refs = load_scene(b.write(tmp_path / "tt.glb")).materials[0].texture_refs()
    assert len(refs) == 5
    for ref in refs.values():
        assert (ref.offset, ref.scale, ref.rotation) == ((0.25, 0.5), (2.0, 3.0), 0.5)


def test_points_and_lines_are_drawn():
    scene = load_scene(_sample("MeshPrimitiveModes"))
    assert not any("skipped" in w for w in scene.warnings)
    doc = json.loads(_sample("MeshPrimitiveModes").read_text())
    modes = [p.get("mode", 4) for m in doc["meshes"] for p in m["primitives"]]
    assert len(scene.meshes) == len(modes) == 7
    points = scene.meshes[modes.index(0)]
    count = doc["accessors"][doc["meshes"][modes.index(0)]["primitives"][0]["attributes"]["POSITION"]]["count"]
    assert points.triangle_count == 8 * count  # an octahedron each
    # a few pixels wide at the default framing: radii a small share of the scene
    size = np.linalg.norm(np.ptp(scene.bounds, axis=0))
    for i, mode in enumerate(modes):
        if mode in (1, 2, 3):
            extent = np.ptp(scene.meshes[i].positions, axis=0)
            assert 0 < extent.min() < 0.03 * size  # a thin tube in the flat layout's depth


def test_spec_gloss_conversion_formula():
    from pipeline.gltf.specgloss import convert_factors
    # a dielectric: specular 0.04 grey -> metallic 0, base colour = diffuse
    base, metallic, rough = convert_factors((0.5, 0.2, 0.1, 1.0), (0.04, 0.04, 0.04), 0.7)
    assert metallic == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(base[:3], (0.5, 0.2, 0.1), atol=1e-6)
    assert rough == pytest.approx(0.3)
    # a metal: black diffuse, coloured specular -> metallic 1, base colour = specular
    base, metallic, _ = convert_factors((0, 0, 0, 1), (0.9, 0.6, 0.3), 1.0)
    assert metallic == pytest.approx(1.0, abs=1e-3)
    np.testing.assert_allclose(base[:3], (0.9, 0.6, 0.3), atol=2e-3)


def test_spec_gloss_sample_loads_and_matches_its_metal_rough_twin(cache, env):
    """SpecGlossVsMetalRough holds the same bottle twice, once per workflow, side by side: the
    converted one renders like its metallic-roughness twin (each half of a head-on view)."""
    path = _sample("SpecGlossVsMetalRough")
    scene = load_scene(path)
    sg = [m for m in scene.materials if "SpecGloss" in m.name]
    assert sg and all(m.base_color_texture is not None for m in sg if "Bottle" in m.name)
    baked = bake_asset(path, cache)
    frame = render(baked, env, RenderOptions(width=192, height=128, yaw=0, pitch=0,
                                             background="#000000"))
    img = frame.rgba8[..., :3].astype(np.float32) / 255
    left, right = img[:, :96], img[:, 96:]
    # the twins sit mirrored about x = 0: compare their mean colours over bottle pixels
    lm, rm = left[left.sum(axis=2) > 0.05].mean(axis=0), right[right.sum(axis=2) > 0.05].mean(axis=0)
    np.testing.assert_allclose(lm, rm, atol=0.05)


# -- variants, cameras, framing ------------------------------------------------------------------

def _variant_cube(tmp: Path) -> Path:
    b = Builder()
    red = b.material(pbrMetallicRoughness={"baseColorFactor": [1, 0, 0, 1], "metallicFactor": 0},
                     extensions={"KHR_materials_unlit": {}}, name="red")
    blue = b.material(pbrMetallicRoughness={"baseColorFactor": [0, 0, 1, 1], "metallicFactor": 0},
                      extensions={"KHR_materials_unlit": {}}, name="blue")
    mesh = b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=red)
    b.doc["meshes"][mesh]["primitives"][0]["extensions"] = {"KHR_materials_variants": {
        "mappings": [{"material": blue, "variants": [1]}, {"material": red, "variants": [0]}]}}
    b.doc["extensions"] = {"KHR_materials_variants": {"variants": [{"name": "Red"}, {"name": "Blue"}]}}
    b.doc["extensionsUsed"] = ["KHR_materials_variants", "KHR_materials_unlit"]
    b.node(mesh)
    b.doc["cameras"] = [{"type": "perspective", "name": "side",
                         "perspective": {"yfov": 0.6, "znear": 0.1}}]
    b.node(camera=0, translation=[10.0, 0.0, 0.0], rotation=[0, math.sin(math.pi / 4), 0,
                                                              math.cos(math.pi / 4)])
    return b.write(tmp / "variants.glb")


def test_variants_are_listed_and_selected(tmp_path, cache, env):
    path = _variant_cube(tmp_path)
    info = summary(load_scene(path))
    assert info["variants"] == ["Red", "Blue"]
    assert info["extensions"]["KHR_materials_variants"] == "supported"
    baked = bake_asset(path, cache)
    centre = {}
    for variant in (None, "Red", "Blue"):
        frame = render(baked, env, RenderOptions(width=32, height=32, tonemap="none",
                                                 variant=variant))
        centre[variant] = frame.linear[16, 16, :3]
    assert centre[None][0] > 0.5 and centre[None][2] < 0.1
    np.testing.assert_allclose(centre["Red"], centre[None], atol=1e-3)
    assert centre["Blue"][2] > 0.5 and centre["Blue"][0] < 0.1
    with pytest.raises(NotInAsset, match="Green"):
        render(baked, env, RenderOptions(width=32, height=32, variant="Green"))


def test_asset_cameras_are_listed_and_used(tmp_path, cache, env):
    path = _variant_cube(tmp_path)
    info = summary(load_scene(path))
    assert [c["name"] for c in info["cameras"]] == ["side"]
    baked = bake_asset(path, cache)
    for spec in ("0", "side"):
        options = RenderOptions(width=64, height=64, camera=spec, background="transparent")
        cam = request_camera(baked, options)
        np.testing.assert_allclose(cam.position, [10, 0, 0], atol=1e-9)
        np.testing.assert_allclose(cam.basis()[2], [-1, 0, 0], atol=1e-9)  # looks down -X
        assert cam.fov == pytest.approx(math.degrees(0.6))
        frame = render(baked, env, options)
        alpha = frame.linear[..., 3]
        # the 2 m cube 10 m away under a 34 degree fov: about a third of the frame, centred
        assert alpha[32, 32] > 0.5 and alpha[2, 2] == 0 and 0.05 < (alpha > 0.5).mean() < 0.3
    # the real bound, not "it has 0 'side'" (which reads as a count)
    with pytest.raises(NotInAsset, match=r"no camera '7': the asset has 1 camera \(index 0\.\.0 or name: 0 'side'\)"):
        render(baked, env, RenderOptions(width=32, height=32, camera="7"))
    plain = bake_asset(cube(tmp_path / "plain.glb"), cache)
    with pytest.raises(NotInAsset, match="the asset has no cameras"):
        render(plain, env, RenderOptions(width=32, height=32, camera="999999"))


def test_backdrop_is_not_framed(tmp_path, cache, env):
    """A small cube inside a huge inward-facing box (a skybox): framing is the cube's."""
    b = Builder()
    b.node(b.mesh(CUBE_POSITIONS * np.float32(0.5), CUBE_INDICES))
    sky = b.mesh(CUBE_POSITIONS * np.float32(50), CUBE_INDICES[:, ::-1].copy())  # wound inward
    b.doc["meshes"][sky]["name"] = "sky"
    b.node(sky)
    path = b.write(tmp_path / "sky.glb")
    scene = load_scene(path)
    np.testing.assert_allclose(scene.bounds, [[-0.5] * 3, [0.5] * 3])
    assert summary(scene)["backdrop"] == ["sky/0"]
    baked = bake_asset(path, cache)
    cam = request_camera(baked, RenderOptions(width=64, height=64))
    assert np.linalg.norm(cam.position) < 10          # framed on the cube
    assert cam.far > 50 * math.sqrt(3)                 # the sky is still drawn, not clipped
    # an object merely much larger than a neighbour, facing outward, is content, not backdrop
    b2 = Builder()
    b2.node(b2.mesh(CUBE_POSITIONS * np.float32(0.5), CUBE_INDICES))
    b2.node(b2.mesh(CUBE_POSITIONS * np.float32(50), CUBE_INDICES))
    assert load_scene(b2.write(tmp_path / "big.glb")).bounds[1][0] == pytest.approx(50)


def test_flat_asset_is_not_seen_edge_on(tmp_path, cache, env):
    b = Builder()
    plane = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], np.float32)
    b.node(b.mesh(plane, np.array([0, 2, 1, 0, 3, 2], np.uint16),
                  material=b.material(doubleSided=True)))
    baked = bake_asset(b.write(tmp_path / "plane.glb"), cache)
    options = RenderOptions(width=64, height=64, background="transparent")
    cam = request_camera(baked, options)
    view = (cam.position - cam.target) / np.linalg.norm(cam.position - cam.target)
    assert math.degrees(math.asin(view[1])) >= 40
    coverage = (render(baked, env, options).linear[..., 3] > 0.5).mean()
    assert coverage > 0.2
    # a pitch the request sets is kept
    assert request_camera(baked, RenderOptions(width=64, height=64, pitch=5)).position[1] < 0.5
    # the sample the issue names: a morphed floor tile, a tenth as tall as it is wide
    tile = bake_asset(_sample("MorphPrimitivesTest"), cache)
    cam = request_camera(tile, RenderOptions())
    view = (cam.position - cam.target) / np.linalg.norm(cam.position - cam.target)
    assert math.degrees(math.asin(view[1])) >= 40


def test_orthographic_camera_keeps_its_view_height(tmp_path, cache, env):
    """ymag 2 (half the view height) on a 2 m cube: the cube spans half the frame's height."""
    b = Builder()
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES))
    b.doc["cameras"] = [{"type": "orthographic",
                         "orthographic": {"xmag": 2, "ymag": 2, "znear": 0.1, "zfar": 100}}]
    b.node(camera=0, translation=[0.0, 0.0, 10.0])
    baked = bake_asset(b.write(tmp_path / "ortho.glb"), cache)
    frame = render(baked, env, RenderOptions(width=64, height=64, camera="0",
                                             background="transparent", msaa=0))
    rows = (frame.linear[:, 32, 3] > 0.5).sum()
    assert abs(rows - 32) <= 2
