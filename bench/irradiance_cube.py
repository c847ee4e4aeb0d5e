"""The raster's diffuse image light against the exact cosine integral of the cube's texels
(core.irradiance), on every shipped environment and a coloured studio: the order-2 SH the raster
read before, and irradiance cubes of a few face sizes read as the raster reads them (GL, seamless
bilinear), relative error per channel, max and mean over random normals (issue 30):
`PYTHONPATH=. python -m bench.irradiance_cube --sizes 8 12 16 24 32`."""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

FRAG = """#version 430
uniform samplerCube u_cube;
uniform sampler2D u_normals;
out vec4 f_color;
void main() { f_color = vec4(texture(u_cube, texelFetch(u_normals, ivec2(gl_FragCoord.xy), 0).xyz).rgb, 1.0); }
"""


def gl_reads(cube: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Seamless bilinear reads of a 6 x S x S x 3 cube at unit normals (N x 3) on the GL context."""
    import moderngl

    import shaders
    from gl import context as gl
    from renderer.raster import gpu
    ctx = gl.get_context()
    ctx.enable_direct(gpu.GL_TEXTURE_CUBE_MAP_SEAMLESS)
    tex = gpu.irradiance_texture(cube)
    n = len(normals)
    w = 256
    h = -(-n // w)
    grid = np.zeros((h * w, 4), np.float32)
    grid[:n, :3] = normals
    ntex = ctx.texture((w, h), 4, grid.tobytes(), dtype="f4")
    ntex.filter = (moderngl.NEAREST, moderngl.NEAREST)
    prog = ctx.program(vertex_shader=shaders.load("screen_triangle.vert"),
                       fragment_shader=FRAG)
    prog["u_cube"].value, prog["u_normals"].value = 0, 1  # type: ignore[union-attr]  # uniforms
    tex.use(0)
    ntex.use(1)
    out = ctx.texture((w, h), 4, dtype="f4")
    fbo = ctx.framebuffer([out])
    fbo.use()
    fbo.viewport = (0, 0, w, h)
    gl.fullscreen_vao(prog).render(vertices=3)
    got = np.frombuffer(out.read(), np.float32).reshape(-1, 4)[:n, :3]
    for r in (fbo, out, ntex, tex):
        r.release()
    return got.astype(np.float64)


def environments(tmp: Path) -> list[tuple[str, str]]:
    from core.cubemap import equirect_direction
    from pipeline.environment.panorama import list_bundled, load_panorama, write_rgbe
    pixels = load_panorama("studio").pixels
    h, w = pixels.shape[:2]
    uu, vv = np.meshgrid((np.arange(w) + 0.5) / w, (np.arange(h) + 0.5) / h)
    up = equirect_direction(uu, vv)[..., 1:2] > 0   # tests/test_raytrace_diffuse.py's tinted studio
    write_rgbe(str(tmp / "tinted_studio.hdr"), (pixels * np.where(up, [0.55, 0.75, 1.6], [1.5, 0.9, 0.45])).astype(np.float32))
    return [(name, name) for name in list_bundled()] + [("tinted_studio", str(tmp / "tinted_studio.hdr"))]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[8, 12, 16, 24, 32])
    ap.add_argument("--face", type=int, default=128, help="the environment bake's face size")
    ap.add_argument("--normals", type=int, default=4096)
    args = ap.parse_args(argv)
    from core import irradiance
    from core.sh import sh_irradiance
    from pipeline.bake import bake_environment
    rng = np.random.default_rng(30)
    n = rng.normal(size=(args.normals, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    print(f"relative error against the texel integral, {args.normals} normals, {args.face} px bakes:"
          " max% (R G B) / mean% (R G B)")
    with tempfile.TemporaryDirectory() as tmp:
        for name, source in environments(Path(tmp)):
            env = bake_environment(source, Path(tmp) / "cache", face_size=args.face)
            exact = irradiance.irradiance(env.specular[0], n)
            reads = {"sh": sh_irradiance(env.irradiance_sh, n)}
            for s in args.sizes:
                reads[f"cube{s}"] = gl_reads(irradiance.irradiance_cube(env.specular[0], s), n)
            for label, got in reads.items():
                err = np.abs(got / np.maximum(exact, 1e-9) - 1) * 100
                mx, mean = err.max(0), err.mean(0)
                print(f"{name:16s} {label:7s} max {mx[0]:6.3f} {mx[1]:6.3f} {mx[2]:6.3f}"
                      f"  mean {mean[0]:6.3f} {mean[1]:6.3f} {mean[2]:6.3f}")


if __name__ == "__main__":
    main()
