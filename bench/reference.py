"""Physically based reference images of the test scenes, rendered with Mitsuba 3.

    python -m bench.reference --out bench/references [--spp N] [--size N] [--scenes a,b]

Mitsuba's `scalar_rgb` variant (its LLVM variants crash on this machine) path-traces the
same triangles (written as PLY with their vertex normals), under the same camera
(renderer.view.camera.frame_bounds -> a `perspective` sensor, fov_axis y, box pixel filter) and
the same linear panorama (bench.scenes.load_panorama) as an `envmap`. Mitsuba's envmap maps
a world direction (x, y, z) to u = 0.5 + atan2(-x, z) / 2pi, v = acos(y) / pi, which is
core.cubemap's convention, so no rotation is applied (checked by the mirror-sphere test).
Materials: `dielectric` / `roughdielectric` (GGX, alpha = roughness^2) for glass,
`conductor` (perfect mirror) for the mirror, `roughplastic` (GGX, nonlinear=False) for the
plastic spheres, `principled` for the other opaque spheres. Mitsuba's GGX is single-scattering
and its principled metal's Fresnel is the base colour: at roughness 0.6 its white metal keeps
0.82 of a uniform light where ours (multiple scattering compensated, Schlick to white at
grazing) keeps 1.0, so rough_metal_sphere's reference is 8-26% darker than every method of
ours by design (bench/RESULTS.md, "Mitsuba's rough gold").

The frosted sphere's committed reference used --spp 1024 (at 256 its noise alone is 0.04).
Each scene writes <name>.exr (linear RGBA) and <name>.npy (float16 H x W x 4: linear RGB and
object coverage, from a second pass with the emitter hidden) so the tests need no Mitsuba.
The renderer reads a cubemap resampled from this panorama (face size 256 by default, 1024
texels around the horizon, the panorama's own width), so background texels agree closely.
"""
from __future__ import annotations

import argparse
import logging
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import scenes

log = logging.getLogger(__name__)

REFERENCES = Path(__file__).resolve().parent / "references"
# Scene -> image size. The spheres the tests compare most closely get 256 px.
DEFAULT_SET = {
    "mirror_sphere": 256,
    "glass_sphere_ior1.3": 256,
    "glass_sphere_ior1.5": 256,
    "glass_sphere_ior1.0": 128,
    "glass_sphere_ior1.15": 128,
    "glass_sphere_ior2.4": 128,
    "glass_ellipsoid_311_ior1.5": 128,
    "glass_bunny_ior1.5": 128,
    "glass_torus_ior1.5": 128,
    "glass_torus_ior2.4": 128,
    "glass_cube_ior1.15": 128,
    "frosted_sphere_ior1.5_r0.3": 128,
    # issue 26's real-asset glass: textured (256 spp) and absorbing (1024 spp: volpath's
    # distance sampling in a purely absorbing medium is noisier)
    "textured_glass_sphere_ior1.5": 128,
    "attenuation_vase_ior1.5": 128,
}


def spec_camera(spec: scenes.SceneSpec, width: int, height: int):
    """The camera every method and the reference use for a scene (renderer.view.camera convention)."""
    from core.scene import transformed_bounds
    from renderer.view.camera import frame_bounds

    pos, _, _ = scenes.mesh_arrays(spec.mesh)
    lo, hi = transformed_bounds(pos, spec.matrix)
    return frame_bounds(np.stack([lo, hi]), width, height, spec.yaw, spec.pitch, spec.fov,
                        spec.camera_distance(width, height))


def _write_ply(path: str, pos: np.ndarray, nrm: np.ndarray, idx: np.ndarray,
               uv: np.ndarray | None = None) -> None:
    fields = [("p", "<f4", 3), ("n", "<f4", 3)] + ([("uv", "<f4", 2)] if uv is not None else [])
    vert = np.empty(len(pos), dtype=fields)
    vert["p"], vert["n"] = pos, nrm
    if uv is not None:  # glTF's UVs as they are: Mitsuba's bitmap also puts v = 0 on row 0
        vert["uv"] = uv
    faces = np.empty(len(idx), dtype=[("c", "u1"), ("i", "<i4", 3)])
    faces["c"], faces["i"] = 3, idx
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(pos)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property float nx\nproperty float ny\nproperty float nz\n"
              + ("property float u\nproperty float v\n" if uv is not None else "") +
              f"element face {len(idx)}\nproperty list uchar int vertex_indices\nend_header\n")
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(vert.tobytes())
        f.write(faces.tobytes())


def _bsdf(mat, texture: str | None = None) -> dict:
    rgb = {"type": "rgb", "value": [float(c) for c in mat.base_color[:3]]}
    if mat.transmission > 0:
        if mat.roughness > 0:
            return {"type": "roughdielectric", "distribution": "ggx",
                    "alpha": float(mat.roughness) ** 2, "int_ior": float(mat.ior), "ext_ior": 1.0}
        out = {"type": "dielectric", "int_ior": float(mat.ior), "ext_ior": 1.0}
        if texture:  # the baseColorTexture tints what is transmitted: Mitsuba applies
            # specular_transmittance at every refraction, so it gets sqrt(linear base), the
            # tint per crossing of Cycles and of our renderers (sqrt(c_in) sqrt(c_out))
            out["specular_transmittance"] = _bitmap(texture, per_crossing=True)
        return out
    if mat.metallic >= 1 and mat.roughness == 0 and min(mat.base_color[:3]) >= 1:
        return {"type": "conductor", "material": "none"}
    if mat.name.startswith("plastic"):
        # glTF's dielectric: a GGX layer over a diffuse base that gets what the layer's
        # directional albedo leaves (nonlinear=False: no extra saturation from internal bounces)
        return {"type": "roughplastic", "distribution": "ggx", "alpha": float(mat.roughness) ** 2,
                "int_ior": float(mat.ior), "ext_ior": 1.0, "diffuse_reflectance": rgb,
                "nonlinear": False}
    return {"type": "principled", "base_color": rgb, "metallic": float(mat.metallic),
            "roughness": float(mat.roughness), "specular": 0.5}


def _bitmap(texture: str, per_crossing: bool = False) -> dict:
    """The sRGB texture as Mitsuba decodes it; `per_crossing`: sqrt of its linear values,
    decoded here (a raw float bitmap)."""
    import mitsuba as mi

    img = scenes.texture_srgb(texture)
    raw = False
    if per_crossing:
        c = img.astype(np.float32) / 255
        img = np.sqrt(np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)).astype(np.float32)
        raw = True
    bmp = mi.Bitmap(np.ascontiguousarray(img), pixel_format=mi.Bitmap.PixelFormat.RGB)
    # Mitsuba's bitmap wraps u and v alike; the glTF sampler clamps v, which only the pole
    # rows (white) would notice
    return {"type": "bitmap", "bitmap": bmp, "raw": raw, "filter_type": "bilinear",
            "wrap_mode": "repeat"}


def _interior(mat) -> dict | None:
    """KHR_materials_volume's Beer-Lambert absorption as a purely absorbing medium."""
    import math

    if not (mat.transmission > 0 and math.isfinite(mat.attenuation_distance)):
        return None
    sigma = [-math.log(max(float(c), 1e-6)) / float(mat.attenuation_distance)
             for c in mat.attenuation_color]
    top = max(max(sigma), 1e-9)  # Mitsuba's rgb values must lie in [0, 1]: scale carries the rest
    return {"type": "homogeneous", "sigma_t": {"type": "rgb", "value": [v / top for v in sigma]},
            "scale": top, "albedo": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}


def render_reference(spec: scenes.SceneSpec, size: int, spp: int = 256,
                     panorama: np.ndarray | None = None, timing: dict | None = None) -> np.ndarray:
    """Mitsuba path-traced linear H x W x 4 float32: RGB and object coverage. `panorama`
    (linear H x W x 3) replaces the scene's environment, e.g. a constant one for a furnace.
    `timing` (a dict) gets "ms": the beauty pass's scene load (mi.load_dict: shapes, BVH,
    textures, emitter) plus render, the peer's time in `bench accuracy` (the coverage pass and
    writing the PLY are bench plumbing, not Mitsuba's work)."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    cam = spec_camera(spec, size, size)
    pano = scenes.load_panorama(spec.env) if panorama is None else panorama
    with tempfile.TemporaryDirectory() as tmp:
        ply = os.path.join(tmp, "mesh.ply")
        _write_ply(ply, *scenes.mesh_arrays(spec.mesh), scenes.mesh_uvs(spec.mesh))
        sensor = {
            "type": "perspective", "fov": float(cam.fov), "fov_axis": "y",
            "near_clip": float(cam.near) * 0.5, "far_clip": float(cam.far) * 4,
            "to_world": mi.ScalarTransform4f().look_at(
                origin=cam.position.tolist(), target=cam.target.tolist(), up=cam.up.tolist()),
            "film": {"type": "hdrfilm", "width": size, "height": size,
                     "rfilter": {"type": "box"}, "pixel_format": "rgba"},
            "sampler": {"type": "stratified", "sample_count": spp},
        }
        shape = {"type": "ply", "filename": ply, "face_normals": False,
                 "to_world": mi.ScalarTransform4f(spec.matrix.tolist()),
                 "bsdf": _bsdf(spec.material, spec.texture)}
        medium = _interior(spec.material)
        if medium is not None:
            shape["interior"] = medium
        # volpath for an absorbing interior (path ignores media); the same depth either way
        kind = "volpath" if medium is not None else "path"
        env = {"type": "envmap", "bitmap": mi.Bitmap(np.ascontiguousarray(pano, np.float32))}
        t0 = time.perf_counter()
        beauty = mi.load_dict({"type": "scene", "sensor": sensor, "shape": shape, "env": env,
                               "integrator": {"type": kind, "max_depth": 64, "rr_depth": 64}})
        rgb = np.array(mi.render(beauty), np.float32)[..., :3]
        if timing is not None:
            timing["ms"] = (time.perf_counter() - t0) * 1e3
        sensor["sampler"] = {"type": "stratified", "sample_count": 16}
        # With the emitter hidden, alpha is the fraction of a pixel's rays that hit the object.
        mask_scene = mi.load_dict({"type": "scene", "sensor": sensor, "shape": shape, "env": env,
                                   "integrator": {"type": "path", "max_depth": 2,
                                                  "hide_emitters": True}})
        alpha = np.array(mi.render(mask_scene), np.float32)[..., 3:4]
    return np.concatenate([rgb, alpha], axis=-1)


def load_reference(name: str, folder: str | Path = REFERENCES) -> np.ndarray:
    """A committed reference as float32 H x W x 4 (linear RGB, coverage)."""
    path = Path(folder) / f"{name}.npy"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no reference for scene {name!r}; "
                                f"make it with python -m bench.reference --scenes {name}")
    return np.load(path).astype(np.float32)


def relative_mae(image: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Relative mean absolute error of linear RGB: sum |image - ref| / sum |ref| over `mask`
    (default: pixels the object covers in the reference, alpha > 0)."""
    if mask is None:
        mask = reference[..., 3] > 0
    a = image[..., :3][mask].astype(np.float64)
    b = reference[..., :3][mask].astype(np.float64)
    return float(np.abs(a - b).sum() / max(np.abs(b).sum(), 1e-12))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.reference", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(REFERENCES), help="folder for .exr and .npy files")
    parser.add_argument("--spp", type=int, default=256, help="samples per pixel (a square)")
    parser.add_argument("--size", type=int, default=None, help="image size for every scene "
                        "(default: 256 for the main spheres, 128 for the rest)")
    parser.add_argument("--scenes", default=",".join(DEFAULT_SET),
                        help="comma-separated scene names (bench.scenes.SCENES)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in args.scenes.split(","):
        spec = scenes.scene(name)
        size = args.size or DEFAULT_SET.get(name, 128)
        t0 = time.perf_counter()
        img = render_reference(spec, size, args.spp)
        bitmap = mi.Bitmap(img, pixel_format=mi.Bitmap.PixelFormat.RGBA)
        bitmap.convert(component_format=mi.Struct.Type.Float16).write(str(out / f"{name}.exr"))
        np.save(out / f"{name}.npy", img.astype(np.float16))
        log.info("%s: %d px, %d spp, %.1f s", name, size, args.spp, time.perf_counter() - t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
