"""Compressed glTF: Draco, meshopt and KTX2 (Basis Universal) decode to what their uncompressed
siblings hold, and corrupt or hostile streams are refused with an AssetError.

Draco: the shared samples' glTF-Draco variants. meshopt and KTX2: files made here with the same
wheels' encoders (meshopt's encode_gltf_buffer and filters; alktx2, a basisu build) from the
Duck sample (bench/compressed.py). Renders are compared with FLIP (LDR, tone-mapped), mean below 0.05.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from bench.compressed import ktx2_variant, meshopt_variant
from core.cubemap import default_face_size
from core.errors import AssetError, LimitExceeded, MalformedAsset
from core.options import RenderOptions
from pipeline.bake import bake_asset, bake_environment
from pipeline.environment.panorama import DEFAULT_ENVIRONMENT
from pipeline.ingest import load_scene
from renderer import render

SAMPLES = Path(__file__).resolve().parent / "assets" / "gltf-samples"
DRACO = sorted(SAMPLES.glob("*/glTF-Draco/*.gltf"))
# Every variant folder (Draco, Quantized, Embedded, Binary) beside a primary glTF/ one.
ALL_VARIANTS = sorted(p for p in [*SAMPLES.glob("*/glTF-*/*.gltf"), *SAMPLES.glob("*/glTF-*/*.glb")]
                      if (p.parent.parent / "glTF" / (p.stem + ".gltf")).exists())
# The material test models differ from each other only in their materials, which a .glb holds
# as its .gltf does: their GLB twins re-test one container reader at a render each. Every other
# variant stays (each codec, and GLBs of skins, morphs, instancing, negative scale); every
# variant still loads in test_gltf_features.py::test_every_sample_loads.
MATERIAL_ONLY = {"AnisotropyRotationTest", "AttenuationTest", "ClearCoatTest", "EmissiveStrengthTest",
                 "SpecularTest", "TextureSettingsTest", "TransmissionRoughnessTest"}
VARIANTS = [p for p in ALL_VARIANTS
            if not (p.parent.name == "glTF-Binary" and p.parent.parent.name in MATERIAL_ONLY)]
SIZE = 128
MEAN_FLIP = 0.05


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("compressed-cache")


@pytest.fixture(scope="module")
def env(cache):
    return bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(SIZE))


def _flip(a, b) -> float:
    import flip_evaluator as flip
    ref = a.rgba8[..., :3].astype(np.float32) / 255
    test = b.rgba8[..., :3].astype(np.float32) / 255
    return float(flip.evaluate(ref, test, "LDR", applyMagma=False)[1])


def _render(path, cache, env):
    frame = render(bake_asset(path, cache), env,
                   RenderOptions(width=SIZE, height=SIZE, yaw=30, pitch=20))
    assert np.isfinite(frame.linear).all()
    return frame


def _primary(variant: Path) -> Path:
    return variant.parent.parent / "glTF" / (variant.stem + ".gltf")


def test_every_draco_sample_is_found():
    assert len(DRACO) >= 4 and set(DRACO) <= set(VARIANTS)


@pytest.mark.parametrize("path", VARIANTS, ids=lambda p: f"{p.parent.parent.name}/{p.parent.name}")
def test_variant_matches_primary(path, cache, env):
    """Draco / Quantized / Embedded / Binary variants: the same triangles, bounds within the
    codec's quantisation, and a render within FLIP 0.05 of the primary's."""
    draco, plain = load_scene(path), load_scene(_primary(path))
    assert draco.triangle_count == plain.triangle_count
    assert np.allclose(draco.bounds, plain.bounds, atol=2e-3 * np.ptp(plain.bounds, axis=0).max())
    assert _flip(_render(_primary(path), cache, env), _render(path, cache, env)) < MEAN_FLIP


# -- meshopt ------------------------------------------------------------------------------------

DUCK = SAMPLES / "Duck" / "glTF" / "Duck.gltf"


def _meshopt_duck(tmp: Path, extension: str = "EXT_meshopt_compression") -> Path:
    return meshopt_variant(DUCK, tmp, extension)


def _canonical(tri: np.ndarray) -> np.ndarray:
    """Each triangle rotated to start at its smallest index (same winding)."""
    k = tri.argmin(axis=1)
    return np.stack([tri[np.arange(len(tri)), (k + j) % 3] for j in range(3)], axis=1)


@pytest.mark.parametrize("extension", ["EXT_meshopt_compression", "KHR_meshopt_compression"])
def test_meshopt_round_trip(extension, tmp_path, cache, env):
    path = _meshopt_duck(tmp_path, extension)
    plain_path = SAMPLES / "Duck" / "glTF" / "Duck.gltf"
    packed, plain = load_scene(path), load_scene(plain_path)
    assert packed.triangle_count == plain.triangle_count
    assert np.array_equal(packed.meshes[0].positions, plain.meshes[0].positions)
    # the index codec may rotate a triangle's corners (winding kept)
    assert np.array_equal(_canonical(packed.meshes[0].indices), _canonical(plain.meshes[0].indices))
    # 8-bit octahedral normals: within a couple of degrees
    dots = np.einsum("ij,ij->i", packed.meshes[0].normals, plain.meshes[0].normals)
    assert dots.min() > 0.99
    assert _flip(_render(plain_path, cache, env), _render(path, cache, env)) < MEAN_FLIP


def test_meshopt_corrupt_stream_is_refused(tmp_path):
    path = _meshopt_duck(tmp_path)
    blob = bytearray((tmp_path / "Duck.meshopt.bin").read_bytes())
    blob[:] = bytes(len(blob))  # the header byte of every stream is wrong now
    (tmp_path / "Duck.meshopt.bin").write_bytes(bytes(blob))
    with pytest.raises(MalformedAsset, match=r"bufferView \d+.*meshopt stream does not decode"):
        load_scene(path)


def test_meshopt_absurd_declared_size_is_refused(tmp_path):
    path = _meshopt_duck(tmp_path)
    doc = json.loads(path.read_text())
    spec = doc["bufferViews"][0]["extensions"]["EXT_meshopt_compression"]
    spec["count"] = 3 * 2**30
    path.write_text(json.dumps(doc))
    with pytest.raises(LimitExceeded, match="bufferView 0"):
        load_scene(path)


# -- Draco hostile streams ------------------------------------------------------------------

def _draco_box(tmp: Path) -> tuple[Path, dict]:
    src = SAMPLES / "Box" / "glTF-Draco"
    for f in src.iterdir():
        shutil.copy(f, tmp / f.name)
    path = tmp / "Box.gltf"
    return path, json.loads(path.read_text())


def test_draco_corrupt_stream_is_refused(tmp_path):
    path, doc = _draco_box(tmp_path)
    bin_path = tmp_path / doc["buffers"][0]["uri"]
    blob = bytearray(bin_path.read_bytes())
    blob[8:] = bytes(len(blob) - 8)  # keep the DRACO magic, zero the rest
    bin_path.write_bytes(bytes(blob))
    with pytest.raises(MalformedAsset, match=r"Draco, bufferView 0"):
        load_scene(path)


def test_draco_absurd_accessor_count_is_refused(tmp_path):
    path, doc = _draco_box(tmp_path)
    doc["accessors"][1]["count"] = 10_000_000  # claims a bomb from a 118-byte stream
    path.write_text(json.dumps(doc))
    with pytest.raises(AssetError, match="Draco"):
        load_scene(path)


# -- KTX2 ---------------------------------------------------------------------------------------

def _ktx2_duck(tmp: Path) -> Path:
    return ktx2_variant(DUCK, tmp)


def test_ktx2_round_trip(tmp_path, cache, env):
    path = _ktx2_duck(tmp_path)
    scene, plain = load_scene(path), load_scene(SAMPLES / "Duck" / "glTF" / "Duck.gltf")
    assert not scene.warnings
    a, b = scene.textures[0].image, plain.textures[0].image
    assert a.shape == b.shape and a.dtype == np.uint8
    assert np.abs(a.astype(int) - b.astype(int)).mean() < 4  # UASTC is near-lossless
    assert _flip(_render(SAMPLES / "Duck" / "glTF" / "Duck.gltf", cache, env),
                 _render(path, cache, env)) < MEAN_FLIP


def test_ktx2_corrupt_or_huge_is_a_warning(tmp_path):
    import struct
    path = _ktx2_duck(tmp_path)
    blob = bytearray((tmp_path / "DuckCM-0.ktx2").read_bytes())
    struct.pack_into("<II", blob, 20, 1 << 20, 1 << 20)  # declares 2^40 pixels
    (tmp_path / "DuckCM-0.ktx2").write_bytes(bytes(blob))
    scene = load_scene(path)  # the asset still loads, factor only
    assert any("pixels, over the limit" in w for w in scene.warnings)
    blob[20:28] = struct.pack("<II", 512, 512)
    (tmp_path / "DuckCM-0.ktx2").write_bytes(bytes(blob[:300]))  # truncated: levels past the end
    scene = load_scene(path)
    assert not scene.textures and any("KTX2 image does not decode" in w for w in scene.warnings)
    assert scene.materials[0].base_color_texture is None  # factor only, still renders


# -- WebP ---------------------------------------------------------------------------------------

def test_webp_texture_is_preferred_and_decoded(tmp_path, cache, env):
    """EXT_texture_webp (Pillow): the WebP source is the one read when the texture names both."""
    import io

    from PIL import Image

    doc = json.loads(DUCK.read_text())
    for f in DUCK.parent.iterdir():
        shutil.copy(f, tmp_path / f.name)
    png = Image.open(DUCK.parent / doc["images"][0]["uri"]).convert("RGB")
    webp = io.BytesIO()
    png.save(webp, "WEBP", lossless=True)
    (tmp_path / "duck.webp").write_bytes(webp.getvalue())
    doc["images"].append({"uri": "duck.webp", "mimeType": "image/webp"})
    for t in doc["textures"]:
        t["extensions"] = {"EXT_texture_webp": {"source": 1}}
    doc["extensionsUsed"] = ["EXT_texture_webp"]
    path = tmp_path / "DuckWebp.gltf"
    path.write_text(json.dumps(doc))
    scene = load_scene(path)
    assert scene.textures[0].source.endswith("duck.webp")
    np.testing.assert_array_equal(scene.textures[0].image[..., :3], np.asarray(png))
    assert _flip(_render(DUCK, cache, env), _render(path, cache, env)) < MEAN_FLIP
