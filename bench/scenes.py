"""The glass test scenes, generated in code: one `SceneSpec` list shared by the Mitsuba
reference, the tests and the benchmarks.

Meshes come from primitives (icosphere, box) and ../shared/assets/mesh (bunny, torus), are
centred and scaled to a bounding radius of 1, and are written as .glb files with
KHR_materials_transmission / _ior / _volume so that the whole pipeline (ingest -> bake ->
render) runs on them. A non-uniform scale lives in the node matrix (not in the vertices), so
the renderer has to transform interior vectors itself.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from bench.shapes import mesh_arrays, mesh_uvs
from core.scene import Material

log = logging.getLogger(__name__)



@dataclass(frozen=True)
class SceneSpec:
    """One test scene: a mesh with a material under a panorama, seen from a camera.

    The camera follows renderer.view.camera.frame_bounds at `camera_distance` (the bounding-sphere
    framing the committed references were made with)."""
    name: str
    mesh: str                       # "sphere" | "cube" | "bunny" | "torus"
    material: Material = field(default_factory=Material)
    env: str = "footprint_court"    # bundled panorama name
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)  # node scale (non-uniform allowed)
    yaw: float = 0.0
    pitch: float = 0.0
    fov: float = 40.0
    distance: float | None = None   # camera distance from the bounds centre; None: auto-frame
    texture: str | None = None      # a TEXTURES name: the material's baseColorTexture (TEXCOORD_0)

    @property
    def matrix(self) -> np.ndarray:
        return np.diag([*self.scale, 1.0])

    def camera_distance(self, width: int, height: int) -> float:
        """`distance`, else the bounding sphere's framing (renderer.view.camera.sphere_distance)."""
        if self.distance is not None:
            return self.distance
        from core.scene import transformed_bounds
        from renderer.view.camera import sphere_distance
        lo, hi = transformed_bounds(mesh_arrays(self.mesh)[0], self.matrix)
        return sphere_distance(np.stack([lo, hi]), width, height, self.fov)


def glass(ior: float, roughness: float = 0.0, **kw) -> Material:
    """Clear glass: fully transmissive dielectric, white (transmission is tinted by base colour)."""
    return Material(name=f"glass_{ior}", base_color=(1.0, 1.0, 1.0, 1.0), metallic=0.0,
                    roughness=roughness, transmission=1.0, ior=ior, **kw)


def label_texture(size: int = 256) -> np.ndarray:
    """A stained-glass label (sRGB uint8, size/2 x size x 3) for the lat-long UV sphere: a grid
    of coloured panes with dark leading over u 0.3-0.7, v 0.25-0.75 (the hemisphere facing the
    camera), white elsewhere. White behind: glTF tints transmission once, on the way in
    (renderer.methods.raytrace), Mitsuba's dielectric at every crossing; with the back white the
    two differ only on paths that reflect inside and leave through the label. The panes are
    16+ texels wide so that texture filtering (our mips, Mitsuba's bilinear) hardly matters."""
    h, w = size // 2, size
    img = np.full((h, w, 3), 255, np.uint8)
    panes = np.array([[230, 60, 50], [250, 190, 40], [60, 110, 230], [70, 190, 90],
                      [200, 80, 200], [240, 140, 60]], np.uint8)
    u0, u1, v0, v1 = int(0.3 * w), int(0.7 * w), int(0.25 * h), int(0.75 * h)
    nu, nv = 5, 4
    for a in range(nu):
        for b in range(nv):
            x0, x1 = u0 + (u1 - u0) * a // nu, u0 + (u1 - u0) * (a + 1) // nu
            y0, y1 = v0 + (v1 - v0) * b // nv, v0 + (v1 - v0) * (b + 1) // nv
            img[y0:y1, x0:x1] = 60  # leading
            img[y0 + 2:y1 - 2, x0 + 2:x1 - 2] = panes[(a + 2 * b) % len(panes)]
    return img


TEXTURES = {"label": label_texture}


def texture_srgb(name: str) -> np.ndarray:
    """A TEXTURES image (sRGB uint8 H x W x 3), as written into the .glb."""
    try:
        return TEXTURES[name]()
    except KeyError:
        raise KeyError(f"unknown texture {name!r}; known: {', '.join(TEXTURES)}") from None


def metal(color, roughness: float, name: str) -> Material:
    return Material(name=name, base_color=(*color, 1.0), metallic=1.0, roughness=roughness)


SCENES: dict[str, SceneSpec] = {s.name: s for s in [
    SceneSpec("mirror_sphere", "sphere", metal((1.0, 1.0, 1.0), 0.0, "mirror")),
    SceneSpec("glass_sphere_ior1.0", "sphere", glass(1.0)),
    SceneSpec("glass_sphere_ior1.15", "sphere", glass(1.15)),
    SceneSpec("glass_sphere_ior1.3", "sphere", glass(1.3)),
    SceneSpec("glass_sphere_ior1.5", "sphere", glass(1.5)),
    SceneSpec("glass_sphere_ior2.4", "sphere", glass(2.4)),
    SceneSpec("frosted_sphere_ior1.5_r0.3", "sphere", glass(1.5, roughness=0.3)),
    SceneSpec("glass_ellipsoid_311_ior1.5", "sphere", glass(1.5), scale=(3.0, 1.0, 1.0)),
    SceneSpec("glass_cube_ior1.15", "cube", glass(1.15), yaw=30.0, pitch=20.0),
    SceneSpec("glass_cube_ior1.5", "cube", glass(1.5), yaw=30.0, pitch=20.0),
    SceneSpec("glass_bunny_ior1.5", "bunny", glass(1.5)),
    SceneSpec("glass_torus_ior1.2", "torus", glass(1.2), yaw=20.0, pitch=30.0),
    SceneSpec("glass_torus_ior1.5", "torus", glass(1.5), yaw=20.0, pitch=30.0),
    SceneSpec("glass_torus_ior2.4", "torus", glass(2.4), yaw=20.0, pitch=30.0),
    SceneSpec("steel_sphere", "sphere", metal((0.56, 0.57, 0.58), 0.2, "steel")),
    SceneSpec("rough_metal_sphere", "sphere", metal((1.0, 0.71, 0.29), 0.6, "rough_gold")),
    SceneSpec("dielectric_sphere", "sphere",
              Material(name="red_plastic", base_color=(0.7, 0.05, 0.05, 1.0), metallic=0.0,
                       roughness=0.3)),
    # glTF's dielectric layering against Mitsuba's roughplastic (tests/test_layering.py)
    *(SceneSpec(f"plastic_sphere_r{r}", "sphere",
                Material(name=f"plastic_r{r}", base_color=(0.6, 0.2, 0.08, 1.0), metallic=0.0,
                         roughness=r), pitch=20.0) for r in (0.2, 0.5, 0.8)),
]}

# The speed-vs-accuracy chart's glass set (bench.accuracy): every mesh at every IOR, smooth and
# rough, then real assets and a second panorama.
_VIEW = {"cube": (30.0, 20.0), "torus": (20.0, 30.0)}
for _mesh in ("sphere", "cube", "bunny", "torus"):
    for _ior in (1.15, 1.3, 1.5, 2.4):
        for _name, _r in ((f"glass_{_mesh}_ior{_ior}", 0.0), (f"frosted_{_mesh}_ior{_ior}_r0.3", 0.3)):
            SCENES.setdefault(_name, SceneSpec(_name, _mesh, glass(_ior, roughness=_r),
                                               yaw=_VIEW.get(_mesh, (0, 0))[0],
                                               pitch=_VIEW.get(_mesh, (0, 0))[1]))
# The stability suite's cases (bench.stability); geometry from bench.shapes.
SCENES.update({s.name: s for s in [
    SceneSpec("glass_duck_ior1.5", "duck", glass(1.5), yaw=-30.0, pitch=15.0),
    SceneSpec("glass_teapot_ior1.5", "teapot", glass(1.5), yaw=30.0, pitch=20.0),
    SceneSpec("glass_sphere_ior1.5_pisa", "sphere", glass(1.5), env="pisa"),
    SceneSpec("mirror_sphere_pisa", "sphere", metal((1.0, 1.0, 1.0), 0.0, "mirror"), env="pisa"),
    SceneSpec("case_thin_slab", "slab", glass(1.5), yaw=20.0, pitch=15.0),
    SceneSpec("case_grazing", "slab", glass(1.5), yaw=80.0, pitch=5.0),
    # total internal reflection twice inside a Porro prism, seen a little from above
    SceneSpec("case_tir_prism", "prism", glass(1.5), yaw=0.0, pitch=10.0),
    SceneSpec("case_open_mesh", "open_sphere", glass(1.5), pitch=40.0),
    SceneSpec("case_concave_bowl", "bowl", glass(1.5), pitch=35.0),
    SceneSpec("case_tiny", "sphere", glass(1.5), distance=60.0),
    SceneSpec("case_huge", "sphere", glass(1.5), scale=(1e4, 1e4, 1e4)),
    SceneSpec("case_camera_inside", "sphere", glass(1.5), distance=0.5),
    SceneSpec("case_degenerate_triangles", "degenerate_sphere", glass(1.5)),
    SceneSpec("case_flipped_normals", "flipped_sphere", glass(1.5)),
]})
# Real-asset glass for the chart (issue 26): a glass sphere with a stained-glass label as its
# baseColorTexture, and a hollow vase of green glass (KHR_materials_volume attenuation).
SCENES.update({s.name: s for s in [
    SceneSpec("textured_glass_sphere_ior1.5", "uvsphere", glass(1.5), texture="label"),
    SceneSpec("attenuation_vase_ior1.5", "vase",
              glass(1.5, attenuation_color=(0.35, 0.75, 0.55), attenuation_distance=0.15),
              pitch=20.0),
]})


def scene(name: str, **changes) -> SceneSpec:
    """A scene by name, optionally with fields replaced (e.g. env="pisa")."""
    try:
        spec = SCENES[name]
    except KeyError:
        raise KeyError(f"unknown scene {name!r}; known: {', '.join(SCENES)}") from None
    return replace(spec, **changes) if changes else spec


def write_glb(spec: SceneSpec, path: str | Path) -> Path:
    """Write the scene's mesh and material as a binary glTF with the transmission extensions."""
    import pygltflib as g

    pos, nrm, idx = mesh_arrays(spec.mesh)
    uv = mesh_uvs(spec.mesh)
    if spec.texture and uv is None:
        raise ValueError(f"scene {spec.name!r}: texture {spec.texture!r} on mesh {spec.mesh!r}, "
                         "which has no UVs (bench.shapes.mesh_uvs)")
    png = _png(texture_srgb(spec.texture)) if spec.texture else b""
    uv_bytes = uv.tobytes() if uv is not None else b""
    blob = pos.tobytes() + nrm.tobytes() + idx.tobytes() + uv_bytes + png
    mat = spec.material
    extensions: dict[str, dict[str, Any]] = {}
    if mat.transmission > 0:
        extensions["KHR_materials_transmission"] = {"transmissionFactor": mat.transmission}
    if mat.ior != 1.5:
        extensions["KHR_materials_ior"] = {"ior": mat.ior}
    if mat.transmission > 0:
        volume: dict[str, Any] = {"thicknessFactor": 2.0 * float(np.max(spec.scale))}
        if math.isfinite(mat.attenuation_distance):
            volume.update(attenuationDistance=mat.attenuation_distance,
                          attenuationColor=list(mat.attenuation_color))
        extensions["KHR_materials_volume"] = volume
    if mat.uses("specular"):
        extensions["KHR_materials_specular"] = {"specularFactor": mat.specular,
                                                "specularColorFactor": list(mat.specular_color)}
    if mat.uses("clearcoat"):
        extensions["KHR_materials_clearcoat"] = {"clearcoatFactor": mat.clearcoat,
                                                 "clearcoatRoughnessFactor": mat.clearcoat_roughness}
    if mat.uses("dispersion"):
        extensions["KHR_materials_dispersion"] = {"dispersion": mat.dispersion}
    if mat.uses("sheen"):
        extensions["KHR_materials_sheen"] = {"sheenColorFactor": list(mat.sheen_color),
                                             "sheenRoughnessFactor": mat.sheen_roughness}
    views = [
        g.BufferView(buffer=0, byteOffset=0, byteLength=pos.nbytes, target=g.ARRAY_BUFFER),
        g.BufferView(buffer=0, byteOffset=pos.nbytes, byteLength=nrm.nbytes, target=g.ARRAY_BUFFER),
        g.BufferView(buffer=0, byteOffset=pos.nbytes + nrm.nbytes, byteLength=idx.nbytes,
                     target=g.ELEMENT_ARRAY_BUFFER),
    ]
    accessors = [
        g.Accessor(bufferView=0, componentType=g.FLOAT, count=len(pos), type=g.VEC3,
                   min=pos.min(0).tolist(), max=pos.max(0).tolist()),
        g.Accessor(bufferView=1, componentType=g.FLOAT, count=len(nrm), type=g.VEC3),
        g.Accessor(bufferView=2, componentType=g.UNSIGNED_INT, count=idx.size, type=g.SCALAR),
    ]
    attributes = g.Attributes(POSITION=0, NORMAL=1)
    offset = pos.nbytes + nrm.nbytes + idx.nbytes
    if uv is not None:
        views.append(g.BufferView(buffer=0, byteOffset=offset, byteLength=len(uv_bytes),
                                  target=g.ARRAY_BUFFER))
        accessors.append(g.Accessor(bufferView=3, componentType=g.FLOAT, count=len(uv), type=g.VEC2))
        attributes.TEXCOORD_0 = 3
        offset += len(uv_bytes)
    images: list = []
    textures: list = []
    samplers: list = []
    base_tex = None
    if png:
        views.append(g.BufferView(buffer=0, byteOffset=offset, byteLength=len(png)))
        images = [g.Image(bufferView=len(views) - 1, mimeType="image/png", name=spec.texture)]
        # linear, repeat around the seam (u), clamped at the poles (v)
        samplers = [g.Sampler(magFilter=9729, minFilter=9987, wrapS=10497, wrapT=33071)]
        textures = [g.Texture(source=0, sampler=0)]
        base_tex = g.TextureInfo(index=0)
    gltf = g.GLTF2(
        asset=g.Asset(version="2.0", generator="asset-preview bench.scenes"),
        scene=0,
        scenes=[g.Scene(nodes=[0])],
        nodes=[g.Node(mesh=0, name=spec.name, scale=list(map(float, spec.scale)))],
        meshes=[g.Mesh(name=spec.mesh, primitives=[g.Primitive(
            attributes=attributes, indices=2, material=0)])],
        materials=[g.Material(
            name=mat.name, doubleSided=False, extensions=extensions,
            pbrMetallicRoughness=g.PbrMetallicRoughness(
                baseColorFactor=list(mat.base_color), baseColorTexture=base_tex,
                metallicFactor=mat.metallic, roughnessFactor=mat.roughness))],
        accessors=accessors,
        bufferViews=views,
        images=images, samplers=samplers, textures=textures,
        buffers=[g.Buffer(byteLength=len(blob))],
        extensionsUsed=sorted(extensions),
    )
    gltf.set_binary_blob(blob)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    gltf.save_binary(str(path))
    return path


def _png(rgb: np.ndarray) -> bytes:
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="PNG")
    return buf.getvalue()


def baked_asset(spec: SceneSpec, cache_dir: str | Path | None = None):
    """The scene as the renderer sees it, a BakedAsset: through the whole pipeline (write the
    .glb, pipeline.bake.bake_asset) with a cache folder; without one, in memory straight from the
    same arrays and without interior vectors (for tests that edit geometry; the ray tracer
    needs no interior)."""
    if cache_dir is not None:
        from pipeline.bake import bake_asset

        glb = write_glb(spec, Path(cache_dir) / "scenes" / f"{spec.name}.glb")
        return bake_asset(glb, cache_dir)
    from core.baked import BakedAsset, BakedMesh
    from core.scene import transformed_bounds

    if spec.texture:
        raise ValueError(f"scene {spec.name!r} is textured: bake it through a cache folder "
                         "(baked_asset(spec, cache_dir))")

    pos, nrm, idx = mesh_arrays(spec.mesh)
    mesh = BakedMesh(name=spec.mesh, positions=pos, normals=nrm, indices=idx,
                     material=spec.material, transforms=spec.matrix[None].astype(np.float64))
    lo, hi = transformed_bounds(pos, spec.matrix)
    return BakedAsset(key=f"scene:{spec.name}", source=f"bench.scenes:{spec.name}",
                      format="generated", meshes=[mesh], textures=[], bounds=np.stack([lo, hi]))


def load_panorama(name: str) -> np.ndarray:
    """Linear float32 H x W x 3 panorama of a scene's environment, exactly what the bake reads."""
    from pipeline.environment.panorama import load_panorama as _load

    return np.asarray(_load(name).pixels, dtype=np.float32)[..., :3]


def main(argv: list[str] | None = None) -> int:
    """Write every scene as a .glb (python -m bench.scenes OUT_DIR), to bake or render."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m bench.scenes", description=main.__doc__)
    parser.add_argument("out", help="folder for the .glb files")
    args = parser.parse_args(argv)
    for spec in SCENES.values():
        print(write_glb(spec, Path(args.out) / f"{spec.name}.glb"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
