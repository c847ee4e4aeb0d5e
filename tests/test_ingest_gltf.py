"""glTF and plain-mesh ingest: the sample assets against trimesh, and generated files that
exercise each part of the spec (strips, sparse, quantized, strides, hierarchy, extensions)."""
from __future__ import annotations

import math
import pickle

import numpy as np
import pygltflib
import pytest
import trimesh
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder, cube, png_bytes

from core.scene import CLAMP_TO_EDGE, NEAREST
from pipeline.ingest import load_scene

GLTF_SAMPLES = ["BoxTextured.glb", "CesiumMilkTruck.glb", "Duck.glb", "TestScene.gltf",
                "rgb_cube_with_primitives.gltf"]
MESH_SAMPLES = ["bunny.ply", "suzanne.ply", "torus.STL"]
# (materials, textures) as the files define them: the truck's two textures share one image.
COUNTS = {"BoxTextured.glb": (1, 1), "CesiumMilkTruck.glb": (4, 1), "Duck.glb": (1, 1),
          "TestScene.gltf": (5, 0), "rgb_cube_with_primitives.gltf": (3, 0)}


def trimesh_triangles(path) -> int:
    loaded = trimesh.load(path)
    if isinstance(loaded, trimesh.Scene):
        return sum(len(g.faces) for g in loaded.dump())
    return len(loaded.faces)


@pytest.mark.parametrize("name", GLTF_SAMPLES + MESH_SAMPLES)
def test_sample_loads_like_trimesh(assets, name):
    path = next(assets.glob(f"*/{name}"))
    scene = load_scene(path)
    assert scene.triangle_count == trimesh_triangles(path)
    peer = trimesh.load(path)
    np.testing.assert_allclose(scene.bounds, peer.bounds, rtol=1e-4, atol=1e-4)
    assert scene.files[0] == str(path.resolve())
    for mesh in scene.meshes:
        assert mesh.positions.dtype == np.float32 and mesh.indices.dtype == np.uint32
        assert mesh.normals.shape == mesh.positions.shape
        np.testing.assert_allclose(np.linalg.norm(mesh.normals, axis=1), 1.0, atol=1e-4)
    if name in COUNTS:
        assert (len(scene.materials), len(scene.textures)) == COUNTS[name]


def test_sample_files_listed_and_textures_decode(assets):
    scene = load_scene(assets / "gltf" / "TestScene.gltf")
    assert sorted(scene.files) == sorted(str((assets / "gltf" / f).resolve())
                                         for f in ("TestScene.gltf", "TestScene.bin"))
    duck = load_scene(assets / "gltf" / "Duck.glb")
    image = duck.textures[0].image
    assert image.shape == (512, 512, 4) and image.dtype == np.uint8
    assert duck.materials[0].base_color_texture.texture == 0


def test_uvs_stay_in_gltf_convention(assets):
    """trimesh flips v to v=0 at the image bottom; we keep glTF's (v=0 at the top)."""
    path = assets / "gltf" / "Duck.glb"
    ours = load_scene(path).meshes[0]
    geom = next(iter(trimesh.load(path, process=False).geometry.values()))
    np.testing.assert_allclose(ours.uv0[:, 0], geom.visual.uv[:, 0], atol=1e-6)
    np.testing.assert_allclose(ours.uv0[:, 1], 1.0 - geom.visual.uv[:, 1], atol=1e-6)


def test_texture_row_zero_is_the_image_top(tmp_path):
    pixels = np.zeros((2, 2, 4), np.uint8)
    pixels[0, 0] = (255, 0, 0, 255)   # top left red
    pixels[1, 1] = (0, 0, 255, 255)   # bottom right blue
    b = Builder()
    tex = b.image(png_bytes(pixels))
    b.doc["samplers"] = [{"magFilter": NEAREST, "wrapS": CLAMP_TO_EDGE}]
    b.doc["textures"][tex]["sampler"] = 0
    mat = b.material(pbrMetallicRoughness={"baseColorTexture": {"index": tex}})
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=mat))
    scene = load_scene(b.write(tmp_path / "t.glb"))
    texture = scene.textures[0]
    assert "not decoded" in repr(texture)
    restored = pickle.loads(pickle.dumps(texture))
    for t in (texture, restored):
        assert tuple(t.image[0, 0]) == (255, 0, 0, 255)
        assert tuple(t.image[1, 1]) == (0, 0, 255, 255)
        assert t.sampler.mag_filter == NEAREST and t.sampler.wrap_s == CLAMP_TO_EDGE


@pytest.mark.parametrize("how", ["glb", "gltf", "data"])
def test_containers(tmp_path, how):
    scene = load_scene(cube(tmp_path / f"c.{'glb' if how == 'glb' else 'gltf'}", how))
    assert scene.triangle_count == 12
    np.testing.assert_allclose(scene.bounds, [[-1, -1, -1], [1, 1, 1]])
    assert len(scene.files) == (2 if how == "gltf" else 1)


def test_missing_normals_are_flat(tmp_path):
    scene = load_scene(cube(tmp_path / "c.glb"))
    mesh = scene.meshes[0]
    assert len(mesh.positions) == 36  # split vertices: one normal per face
    tri = mesh.positions[mesh.indices]
    face = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    face /= np.linalg.norm(face, axis=1, keepdims=True)
    np.testing.assert_allclose(mesh.normals[mesh.indices[:, 0]], face, atol=1e-6)
    # an axis-aligned cube: every flat normal is an axis
    assert np.allclose(np.abs(mesh.normals).max(axis=1), 1.0)


@pytest.mark.parametrize("mode,indices", [
    (5, [0, 1, 2, 3]),          # strip: (0,1,2), (1,3,2)
    (6, [0, 1, 3, 2]),          # fan: (1,3,0), (3,2,0)
    (4, [0, 1, 2, 1, 3, 2]),    # list
])
def test_strips_and_fans_keep_the_winding(tmp_path, mode, indices):
    quad = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    b = Builder()
    b.node(b.mesh(quad, np.array(indices, np.uint8), mode=mode))
    mesh = load_scene(b.write(tmp_path / "q.glb")).meshes[0]
    assert mesh.triangle_count == 2
    assert np.allclose(mesh.normals, [0, 0, 1], atol=1e-6)  # counter-clockwise seen from +z


def test_non_indexed_quantized_interleaved_and_sparse(tmp_path):
    b = Builder()
    # KHR_mesh_quantization: int16 normalized positions, scaled by the node to 2 m.
    q = np.array([[0, 0, 0], [32767, 0, 0], [0, 32767, 0]], np.int16)
    b.node(b.mesh(q), scale=[2.0, 2.0, 2.0])
    b.doc["accessors"][0]["normalized"] = True
    # interleaved POSITION + TEXCOORD_0 (uint8 normalized) in one strided view
    pos = np.array([[5, 0, 0], [6, 0, 0], [5, 1, 0]], np.float32)
    uv = np.array([[0, 0], [255, 0], [0, 255]], np.uint8)
    rec = np.zeros(3, dtype=[("p", "<f4", 3), ("uv", "u1", 2), ("pad", "u1", 2)])
    rec["p"], rec["uv"] = pos, uv
    view = b.view(rec.tobytes(), stride=16)
    b.doc["accessors"] += [
        {"bufferView": view, "componentType": 5126, "count": 3, "type": "VEC3",
         "min": [5, 0, 0], "max": [6, 1, 0]},
        {"bufferView": view, "byteOffset": 12, "componentType": 5121, "normalized": True,
         "count": 3, "type": "VEC2"}]
    b.doc["meshes"].append({"primitives": [{"attributes": {"POSITION": 1, "TEXCOORD_0": 2}}]})
    b.node(1)
    # sparse: no bufferView (zeros) with two vertices substituted
    sparse_idx = b.view(np.array([1, 2], np.uint16).tobytes())
    sparse_val = b.view(np.array([[0, 0, 9], [0, 1, 9]], np.float32).tobytes())
    b.doc["accessors"].append({"componentType": 5126, "count": 3, "type": "VEC3",
                               "sparse": {"count": 2,
                                          "indices": {"bufferView": sparse_idx, "componentType": 5123},
                                          "values": {"bufferView": sparse_val}}})
    b.doc["meshes"].append({"primitives": [{"attributes": {"POSITION": 3}}]})
    b.node(2)
    b.doc["extensionsUsed"] = b.doc["extensionsRequired"] = ["KHR_mesh_quantization"]
    scene = load_scene(b.write(tmp_path / "q.glb"))
    assert scene.triangle_count == 3
    np.testing.assert_allclose(scene.meshes[0].positions[1], [1, 0, 0], atol=1e-4)
    np.testing.assert_allclose(scene.bounds[1], [6, 2, 9], atol=1e-3)
    interleaved = scene.meshes[1]
    np.testing.assert_allclose(np.unique(interleaved.uv0, axis=0), [[0, 0], [0, 1], [1, 0]])
    sparse = scene.meshes[2]
    assert {tuple(p) for p in sparse.positions} == {(0, 0, 0), (0, 0, 9), (0, 1, 9)}


def test_hierarchy_matrix_trs_and_default_scene(tmp_path):
    b = Builder()
    m = b.mesh(CUBE_POSITIONS, CUBE_INDICES)
    child = b.node(m, root=False, translation=[10, 0, 0])
    # parent: rotate 90 degrees about +y (x -> -z), given as a column-major matrix
    parent = b.node(root=True, matrix=[0, 0, -1, 0, 0, 1, 0, 0, 1, 0, 0, 0, 0, 5, 0, 1],
                    children=[child])
    half = math.sqrt(0.5)
    other = b.node(m, root=False, rotation=[0, half, 0, half], scale=[3, 3, 3])
    b.doc["scenes"] = [{"nodes": [other]}, {"nodes": [parent]}]
    b.doc["scene"] = 1
    scene = load_scene(b.write(tmp_path / "h.glb"))
    assert len(scene.instances) == 1
    np.testing.assert_allclose(scene.bounds, [[-1, 4, -11], [1, 6, -9]], atol=1e-6)


def test_shared_mesh_is_instanced(tmp_path):
    b = Builder()
    m = b.mesh(CUBE_POSITIONS, CUBE_INDICES)
    for x in range(3):
        b.node(m, translation=[3 * x, 0, 0])
    scene = load_scene(b.write(tmp_path / "i.glb"))
    assert len(scene.meshes) == 1 and len(scene.instances) == 3
    assert scene.triangle_count == 36


def test_tangents_computed_for_normal_maps(tmp_path):
    quad = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    # glTF UVs: v grows downwards in the image, so the top edge (y = 1) has v = 0.
    uv = np.array([[0, 1], [1, 1], [0, 0], [1, 0]], np.float32)
    normals = np.tile(np.array([0, 0, 1], np.float32), (4, 1))
    b = Builder()
    tex = b.image(png_bytes(np.full((4, 4, 4), 128, np.uint8)))
    mat = b.material(normalTexture={"index": tex, "scale": 0.5})
    b.node(b.mesh(quad, np.array([0, 1, 2, 1, 3, 2], np.uint16), material=mat,
                  NORMAL=normals, TEXCOORD_0=uv))
    scene = load_scene(b.write(tmp_path / "n.glb"))
    mesh = scene.meshes[0]
    assert scene.materials[0].normal_scale == 0.5
    assert mesh.tangents.shape == (4, 4)
    np.testing.assert_allclose(mesh.tangents[:, :3], np.tile([1, 0, 0], (4, 1)), atol=1e-6)
    # B = cross(N, T) * w must point up the image (+y here), where a normal map's green points
    bitangent = np.cross(mesh.normals, mesh.tangents[:, :3]) * mesh.tangents[:, 3:]
    np.testing.assert_allclose(bitangent, np.tile([0, 1, 0], (4, 1)), atol=1e-6)


def test_lights_and_unlit(tmp_path):
    b = Builder()
    mat = b.material(extensions={"KHR_materials_unlit": {}})
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=mat))
    b.doc["extensions"] = {"KHR_lights_punctual": {"lights": [
        {"type": "spot", "color": [1, 0.5, 0.25], "intensity": 20, "range": 9,
         "spot": {"innerConeAngle": 0.1, "outerConeAngle": 0.5}}]}}
    b.node(translation=[0, 4, 0], extensions={"KHR_lights_punctual": {"light": 0}})
    b.doc["extensionsUsed"] = ["KHR_lights_punctual", "KHR_materials_unlit"]
    scene = load_scene(b.write(tmp_path / "l.glb"))
    assert scene.materials[0].unlit
    (light,) = scene.lights
    assert (light.type, light.color, light.intensity, light.range) == ("spot", (1, 0.5, 0.25), 20, 9)
    assert (light.inner_cone, light.outer_cone) == (0.1, 0.5)
    np.testing.assert_allclose(light.matrix[:3, 3], [0, 4, 0])


def test_round_trip_pygltflib_materials(tmp_path):
    """A file written by pygltflib with every material extension we read comes back equal."""
    uv = np.zeros((8, 2), np.float32)
    parts = [CUBE_POSITIONS.tobytes(), CUBE_INDICES.tobytes(), uv.tobytes(), uv.tobytes(),
             png_bytes(np.full((2, 2, 4), 200, np.uint8))]
    blob, views = b"", []
    for part in parts:
        blob += b"\0" * (-len(blob) % 4)
        views.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(part)))
        blob += part
    A = pygltflib.Accessor
    accessors = [A(bufferView=0, componentType=5126, count=8, type="VEC3", min=[-1] * 3, max=[1] * 3),
                 A(bufferView=1, componentType=5123, count=36, type="SCALAR"),
                 A(bufferView=2, componentType=5126, count=8, type="VEC2"),
                 A(bufferView=3, componentType=5126, count=8, type="VEC2")]
    attributes = pygltflib.Attributes(POSITION=0, TEXCOORD_0=2, TEXCOORD_1=3)
    tt = {"KHR_texture_transform": {"offset": [0.25, 0.5], "rotation": 0.3, "scale": [2, 3],
                                    "texCoord": 1}}
    materials = [
        pygltflib.Material(
            name="glass", doubleSided=True, alphaMode="BLEND",
            pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(
                baseColorFactor=[0.9, 0.8, 0.7, 0.5], metallicFactor=0.0, roughnessFactor=0.05,
                baseColorTexture=pygltflib.TextureInfo(index=0, extensions=tt)),
            emissiveFactor=[1.0, 0.5, 0.0],
            extensions={
                "KHR_materials_transmission": {"transmissionFactor": 0.95},
                "KHR_materials_ior": {"ior": 1.33},
                "KHR_materials_volume": {"thicknessFactor": 0.2, "attenuationDistance": 0.75,
                                         "attenuationColor": [0.9, 0.95, 1.0]},
                "KHR_materials_emissive_strength": {"emissiveStrength": 4.0}}),
        pygltflib.Material(name="mask", alphaMode="MASK", alphaCutoff=0.3),
    ]
    gltf = pygltflib.GLTF2(
        scene=0, scenes=[pygltflib.Scene(nodes=[0, 1])],
        nodes=[pygltflib.Node(mesh=0), pygltflib.Node(mesh=1, translation=[4, 0, 0])],
        meshes=[pygltflib.Mesh(primitives=[pygltflib.Primitive(attributes=attributes, indices=1,
                                                               material=m)]) for m in (0, 1)],
        materials=materials, accessors=accessors, bufferViews=views,
        buffers=[pygltflib.Buffer(byteLength=len(blob))],
        images=[pygltflib.Image(bufferView=4, mimeType="image/png")],
        textures=[pygltflib.Texture(source=0)],
        extensionsUsed=["KHR_materials_transmission", "KHR_materials_ior", "KHR_materials_volume",
                        "KHR_materials_emissive_strength", "KHR_texture_transform"])
    gltf.set_binary_blob(blob)
    path = tmp_path / "round.glb"
    gltf.save_binary(str(path))

    scene = load_scene(path)
    glass, mask = scene.materials
    assert glass.material_class == "transmissive" and mask.material_class == "mask"
    assert glass.name == "glass" and glass.double_sided and glass.alpha_mode == "BLEND"
    assert glass.base_color == pytest.approx((0.9, 0.8, 0.7, 0.5))
    assert (glass.metallic, glass.roughness) == pytest.approx((0.0, 0.05))
    assert glass.transmission == pytest.approx(0.95) and glass.ior == pytest.approx(1.33)
    assert glass.thickness == pytest.approx(0.2)
    assert glass.attenuation_distance == pytest.approx(0.75)
    assert glass.attenuation_color == pytest.approx((0.9, 0.95, 1.0))
    assert glass.emissive == pytest.approx((1.0, 0.5, 0.0)) and glass.emissive_strength == 4.0
    ref = glass.base_color_texture
    assert (ref.offset, ref.rotation, ref.scale, ref.uv_set) == ((0.25, 0.5), 0.3, (2, 3), 1)
    assert mask.alpha_cutoff == pytest.approx(0.3) and mask.transmission == 0.0
    assert scene.triangle_count == 24 and scene.meshes[0].uv1 is not None


def test_plain_mesh_keeps_stored_normals_else_smooth(tmp_path, assets):
    ply = tmp_path / "n.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                   "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
                   "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                   "0 0 0 1 0 0\n1 0 0 1 0 0\n0 1 0 1 0 0\n3 0 1 2\n")
    np.testing.assert_allclose(load_scene(ply).meshes[0].normals, np.tile([1, 0, 0], (3, 1)))
    bunny = load_scene(assets / "mesh" / "bunny.ply").meshes[0]
    peer = trimesh.load(assets / "mesh" / "bunny.ply", process=False)
    cos = np.einsum("ij,ij->i", bunny.normals, peer.vertex_normals)
    assert np.median(cos) > 0.999  # the same area-weighted smooth normals as trimesh's
