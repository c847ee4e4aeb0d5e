"""What a side-by-side with reference viewers needs: mirrored transforms, single-sided culling,
the look-at target, the environment's rotation and coverage alpha, in the raster renderer and
the ray tracer alike."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_render_physics import gradient_radiance, interior, make_env, opts, sphere_asset, sphere_geometry

from core.baked import BakedAsset, BakedMesh
from core.cubemap import env_rotation_matrix, sample_cube
from core.options import RenderOptions
from core.scene import NEAREST, Material, Sampler, Texture, TextureRef
from pipeline.bake import bake_asset, bake_environment
from renderer.raster.render import render
from renderer.view.framing import request_camera

NEGATIVE_SCALE = "gltf-samples/NegativeScaleTest/glTF-Binary/NegativeScaleTest.glb"


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("controls_cache")


def _project(camera, world: np.ndarray) -> tuple[float, float]:
    """Pixel (column, row; row 0 at the top) of a world point."""
    clip = camera.projection_matrix() @ camera.view_matrix() @ np.append(world, 1.0)
    ndc = clip[:3] / clip[3]
    return (ndc[0] + 1) / 2 * camera.width, (1 - ndc[1]) / 2 * camera.height


def _crop(img: np.ndarray, xy, half: int) -> np.ndarray:
    x, y = int(round(xy[0])), int(round(xy[1]))
    return img[y - half:y + half, x - half:x + half]


# --- mirrored transforms ----------------------------------------------------------------------

def test_negative_scale_spheres_match_their_unmirrored_twins(assets, cache):
    """NegativeScaleTest's three rows of spheres: each double-sided sphere under a mirroring
    node (scale -1, determinant < 0) is drawn beside the same sphere un-mirrored. With the
    winding, the front face and the normals following the determinant, each mirrored sphere
    shades as its twin (mean difference < 4% of the twin's mean, linear); drawn inside-out
    (gl_FrontFacing taken for the un-mirrored winding) the white sphere turned chrome and the
    dark blue one black, differences of 30-60%. Baked without ambient occlusion: each placement's
    visibility follows its own surroundings, which differ between the twins."""
    asset = bake_asset(assets / NEGATIVE_SCALE, cache, occlusion=False)
    env = bake_environment("neutral", cache, face_size=128)
    o = RenderOptions(width=512, height=512, tonemap="none", method="opaque", background="env")
    frame = render(asset, env, o)
    camera = request_camera(asset, o)
    spheres = [m for m in asset.meshes if m.name and len(m.transforms) == 2] or \
        [m for m in asset.meshes if len(m.transforms) == 2]
    assert len(spheres) == 3, [m.name for m in asset.meshes]
    for mesh in spheres:
        det = np.linalg.det(mesh.transforms[:, :3, :3])
        assert (det < 0).sum() == 1, det  # one mirrored, one not
        centre = mesh.positions.mean(axis=0)
        crops = []
        for m in mesh.transforms[np.argsort(det)[::-1]]:  # un-mirrored first
            xy = _project(camera, m[:3, :3] @ centre + m[:3, 3])
            crops.append(_crop(frame.linear[..., :3], xy, 10).astype(np.float64))
        plain, mirrored = crops
        # Per-pixel for the rough-lit white sphere; the mirror-like ones reflect the room from
        # two places (parallax alone is 10-15% per pixel), so their mean over the crop.
        if mesh.material.name == "Not So Shiny":
            err = np.abs(mirrored - plain).mean() / plain.mean()
        else:
            err = np.abs(mirrored.mean(axis=(0, 1)) - plain.mean(axis=(0, 1))).mean() / plain.mean()
        print(mesh.material.name, err)
        assert err < 0.04, (mesh.material.name, err)


def _symmetric_radiance(d: np.ndarray) -> np.ndarray:
    """A sky even in x (the mirror plane below): a warm side toward +z, blue above."""
    up, front = np.maximum(d[..., 1:2], 0.0), np.maximum(d[..., 2:3], 0.0)
    return 0.25 + up * np.array([0.2, 0.4, 0.9]) + 1.5 * front ** 4 * np.array([1.0, 0.6, 0.3])


def _corner_asset(mirror: bool) -> BakedAsset:
    """An L of two double-sided quads, one facing +z and one at x = 1 facing -x (seen from
    behind by a camera on the +x side), with an off-axis constant normal map along baked
    tangents and a base colour texture brighter on the right: nothing in it is symmetric.
    `mirror`: placed through diag(-1, 1, 1), the mirror image in x."""
    corners = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0],
                        [1, -1, 0], [1, -1, -2], [1, 1, -2], [1, 1, 0]], np.float32)
    normals = np.array([[0, 0, 1]] * 4 + [[-1, 0, 0]] * 4, np.float32)
    tangents = np.array([[1, 0, 0, 1]] * 4 + [[0, 0, -1, -1]] * 4, np.float32)
    uv = np.tile(np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32), (2, 1))
    colour = np.zeros((8, 8, 4), np.uint8)
    colour[..., :3] = np.linspace(60, 250, 8).astype(np.uint8)[None, :, None] * np.array([1.0, 0.8, 0.5])
    colour[:4, :, 1] //= 3  # and redder in the top half
    colour[..., 3] = 255
    tilt = np.array([0.45, 0.25, 0.86]) / np.linalg.norm([0.45, 0.25, 0.86])
    normal_map = np.empty((4, 4, 4), np.uint8)
    normal_map[..., :3] = np.round((tilt + 1) / 2 * 255).astype(np.uint8)
    normal_map[..., 3] = 255
    textures: list = [Texture("colour", colour, Sampler(mag_filter=NEAREST, min_filter=NEAREST)),
                      Texture("normal", normal_map, Sampler())]
    mat = Material(name="corner", base_color=(1.0, 1.0, 1.0, 1.0), metallic=0.3, roughness=0.35, double_sided=True,
                   base_color_texture=TextureRef(0), normal_texture=TextureRef(1))
    place = np.diag([-1.0, 1.0, 1.0, 1.0]) if mirror else np.eye(4)
    mesh = BakedMesh("corner", corners, normals, np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], np.uint32),
                     mat, place[None], tangents=tangents, uv0=uv)
    world = corners * np.diag(place)[:3]
    return BakedAsset(key=f"corner-{mirror}", source="corner", format="test", meshes=[mesh], textures=textures,
                      bounds=np.array([world.min(0), world.max(0)], np.float64))


@pytest.mark.parametrize("method", ["opaque", "raytrace"])
def test_a_mirrored_instance_renders_as_the_mirror_image(method):
    """Issue 30: an asymmetric, normal-mapped, double-sided object placed through a mirror
    (determinant -1), seen by the mirrored camera under a sky even in the mirror's axis, is the
    left-right mirror image of the unmirrored one: winding and culling, gl_FrontFacing on the
    back face, the tangent frame's handedness, the reflection vector and the horizon all follow
    the determinant (the raster per pixel within 2% but at texel and MSAA edges; the tree's
    samples are not mirrored, so its mean)."""
    env = make_env(_symmetric_radiance, size=32, key="symmetric-x")
    o = opts(method=method, yaw=35.0, pitch=20.0, background="transparent", samples=16, noise=0.0)
    plain = render(_corner_asset(False), env, o).linear
    mirrored = render(_corner_asset(True), env, dataclasses.replace(o, yaw=-35.0)).linear[:, ::-1]
    both = (plain[..., 3] > 0.99) & (mirrored[..., 3] > 0.99)
    assert both.sum() > 0.2 * both.size
    assert np.abs(plain[..., 3] - mirrored[..., 3]).mean() < 0.01  # the same silhouette
    a, b = plain[both, :3], mirrored[both, :3]
    assert a.max(0).min() > 1.3 * a.min(0).max()  # texture and light vary across it
    assert np.abs(a - b).mean() / a.mean() < 0.01, np.abs(a - b).mean() / a.mean()
    if method == "opaque":  # the tree's samples are not mirrored pixel for pixel: its noise
        assert np.quantile(np.abs(a - b).max(1) / a.mean(), 0.98) < 0.02
    # and the image is not its own mirror image: the test sees handedness
    assert np.abs(plain[..., :3] - plain[:, ::-1, :3]).mean() > 5 * np.abs(a - b).mean() * both.mean()


# --- single-sided culling -----------------------------------------------------------------------

def _quad_asset(double_sided: bool) -> BakedAsset:
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    mesh = BakedMesh(name="quad", positions=pos,
                     normals=np.tile([[0, 0, 1.0]], (4, 1)).astype(np.float32),
                     indices=np.array([[0, 1, 2], [0, 2, 3]], np.uint32),
                     material=Material(name="q", base_color=(0.9, 0.1, 0.1, 1.0),
                                       double_sided=double_sided),
                     transforms=np.eye(4)[None])
    return BakedAsset(key=f"quad-{double_sided}", source="quad", format="test", meshes=[mesh],
                      textures=[], bounds=np.array([[-1.0, -1, -0.01], [1, 1, 0.01]]))


@pytest.mark.parametrize("method", ["opaque", "raytrace"])
def test_single_sided_quad_is_invisible_from_behind(method):
    """glTF doubleSided false: back faces are culled. Seen from behind (yaw 180) a single-sided
    quad covers nothing; a double-sided one covers the middle of the frame and is lit on the
    side facing the camera (its normal flipped), like its front."""
    env = make_env(gradient_radiance, size=32, key="gradient")
    behind = opts(method=method, yaw=180, background="transparent")
    single = render(_quad_asset(False), env, behind).linear
    assert single[..., 3].max() == 0.0
    front = render(_quad_asset(False), env, dataclasses.replace(behind, yaw=0)).linear
    assert front[..., 3].mean() > 0.3
    double = render(_quad_asset(True), env, behind).linear
    assert double[..., 3].mean() > 0.3
    mid = (slice(54, 74), slice(54, 74))
    assert double[mid][..., 0].mean() > 0.2 * front[mid][..., 0].mean()


# --- look-at target, environment rotation, coverage alpha ------------------------------------

@pytest.mark.parametrize("method", ["opaque", "raytrace"])
def test_target_puts_the_point_at_the_image_centre(method):
    """Looking at the sphere's right edge (1, 0, 0) puts that edge in the middle column: the
    left half of the frame shows the sphere, the right half the background (auto-framing
    widens to hold the bounding sphere around the new target, so the sphere is smaller)."""
    env = make_env(gradient_radiance, size=32, key="gradient")
    o = opts(method=method, target=(1.0, 0.0, 0.0), background="transparent")
    a = render(sphere_asset(0.0, 0.5), env, o).linear[..., 3]
    row = a[64]
    edge = np.flatnonzero(row > 0.5).max()
    assert abs(edge - 64) <= 2, edge
    assert a[:, :60].mean() > 0.1 and a[:, 68:].max() == 0.0
    # default: the bounds centre, the sphere in the middle
    c = render(sphere_asset(0.0, 0.5), env, dataclasses.replace(o, target=None)).linear[..., 3]
    assert abs(np.flatnonzero(c[64] > 0.5).mean() - 63.5) < 1


@pytest.mark.parametrize("method", ["opaque", "raytrace"])
def test_env_rotation_turns_a_mirror_spheres_reflection(method):
    """A mirror sphere under an environment turned 70 degrees about +Y reflects, at each pixel,
    the environment in the reflected direction turned back by 70 degrees (env_rotation_matrix);
    and turning the camera and the environment together by the same yaw gives the unrotated
    image (the sphere is round), background included."""
    env = make_env(gradient_radiance, size=64, key="gradient")
    o = opts(method=method, env_rotation=70.0, yaw=20, pitch=10)
    frame = render(sphere_asset(1.0, 0.0), env, o).linear[..., :3]
    mask, n, d = sphere_geometry(o)
    sel = interior(mask, n, d, 0.3)
    r = d - 2 * np.einsum("...i,...i->...", d, n)[..., None] * n
    expected = sample_cube(env.specular[0], r @ env_rotation_matrix(70.0).T)
    unrotated = sample_cube(env.specular[0], r)
    err = np.abs(frame[sel] - expected[sel]).mean()
    assert err < 0.015, err
    assert np.abs(frame[sel] - unrotated[sel]).mean() > 5 * err
    base = render(sphere_asset(1.0, 0.0), env, opts(method=method, yaw=0, pitch=10)).linear[..., :3]
    turned = render(sphere_asset(1.0, 0.0), env,
                    opts(method=method, yaw=70, pitch=10, env_rotation=70.0)).linear[..., :3]
    assert np.abs(turned - base).mean() < 0.01


@pytest.mark.parametrize("method", ["opaque", "raytrace"])
@pytest.mark.parametrize("background", ["env", "#336699"])
def test_coverage_alpha_whatever_the_background(method, background):
    """alpha=coverage: the object's coverage in alpha (as over a transparent background) while
    the colour keeps the background; alpha=auto keeps 1 over a background."""
    env = make_env(gradient_radiance, size=32, key="gradient")
    o = opts(method=method, background=background)
    asset = sphere_asset(0.0, 0.5)
    auto = render(asset, env, o)
    assert auto.rgba8[..., 3].min() == 255
    cov = render(asset, env, dataclasses.replace(o, alpha="coverage"))
    ref = render(asset, env, dataclasses.replace(o, background="transparent")).linear[..., 3]
    assert np.abs(cov.linear[..., 3] - ref).max() < 0.02
    assert np.abs(cov.rgba8[..., 3] / 255 - ref).max() < 0.02
    assert cov.linear[..., 3].min() == 0.0 and cov.linear[..., 3].max() == 1.0
    assert np.abs(cov.rgba8[..., :3].astype(int) - auto.rgba8[..., :3]).max() <= 1


# --- sampler wrap (TextureSettingsTest's "texture mirror" rows) -------------------------------

def test_mirrored_repeat_wrap_mirrors_the_texture():
    """glTF MIRRORED_REPEAT (33648): a quad whose u runs 0..2 over a left-dark / right-bright
    ramp shows the ramp and then its mirror image, so the frame is symmetric left to right;
    REPEAT shows the ramp twice."""
    from core.scene import MIRRORED_REPEAT, NEAREST, REPEAT, Sampler, Texture, TextureRef

    ramp = np.zeros((4, 64, 4), np.uint8)
    ramp[..., :3] = np.linspace(10, 250, 64).astype(np.uint8)[None, :, None]
    ramp[..., 3] = 255
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    env = make_env(lambda d: np.full(d.shape[:-1] + (3,), 1.0), size=16, key="white")

    def quad(wrap: int) -> np.ndarray:
        mat = Material(name="ramp", base_color=(1.0, 1.0, 1.0, 1.0), unlit=True,
                       base_color_texture=TextureRef(texture=0))
        mesh = BakedMesh(name="quad", positions=pos,
                         normals=np.tile([[0, 0, 1.0]], (4, 1)).astype(np.float32),
                         indices=np.array([[0, 1, 2], [0, 2, 3]], np.uint32), material=mat,
                         transforms=np.eye(4)[None],
                         uv0=np.array([[0, 1], [2, 1], [2, 0], [0, 0]], np.float32))
        tex = Texture(name="ramp", image=ramp,
                      sampler=Sampler(mag_filter=NEAREST, min_filter=NEAREST, wrap_s=wrap))
        asset = BakedAsset(key=f"ramp-{wrap}", source="ramp", format="test", meshes=[mesh],
                           textures=[tex], bounds=np.array([[-1.0, -1, -0.01], [1, 1, 0.01]]))
        return render(asset, env, opts(method="opaque", distance=2.2, fov=60)).linear[64, :, 0]

    row = quad(MIRRORED_REPEAT)
    inside = np.flatnonzero(row > 0)
    lo, hi = inside.min() + 2, inside.max() - 2
    seg = row[lo:hi + 1]
    assert np.abs(seg - seg[::-1]).max() < 0.05 * seg.max()   # symmetric about the middle
    rep = quad(REPEAT)[lo:hi + 1]
    assert np.abs(rep - rep[::-1]).mean() > 0.2 * rep.max()    # repeat is not


def test_ray_tracer_shows_emission():
    """An emissive sphere (factor x KHR_materials_emissive_strength) under a black sky: the ray
    tracer's pixels on it are the emitted radiance, as the raster pass's (EmissiveStrengthTest
    rendered black before)."""
    black = make_env(lambda d: np.zeros(d.shape[:-1] + (3,)), size=16, key="black")
    asset = sphere_asset(0.0, 0.5, (0.0, 0.0, 0.0, 1.0))
    mesh = asset.meshes[0]
    glowing = dataclasses.replace(mesh, material=dataclasses.replace(
        mesh.material, emissive=(0.5, 1.0, 0.25), emissive_strength=2.0))
    asset = dataclasses.replace(asset, key="glowing-sphere", meshes=[glowing])
    o = opts(method="raytrace")
    mask, n, d = sphere_geometry(o)
    sel = interior(mask, n, d, 0.3)
    for method in ("raytrace", "opaque"):
        got = render(asset, black, dataclasses.replace(o, method=method)).linear[..., :3][sel]
        assert np.abs(got - np.array([1.0, 2.0, 0.5])).max() < 0.01, method


@pytest.mark.parametrize("method", ["single", "wyman"])
def test_env_rotation_reaches_the_refraction_pass(method):
    """A glass sphere through the refraction methods: turning the camera and the environment by
    the same yaw gives the unturned image (refracted and reflected lookups both turn); turning
    the environment alone changes it."""
    from core.options import MaterialOverride

    env = make_env(gradient_radiance, size=64, key="gradient")
    glass = MaterialOverride(transmission=1.0, ior=1.5, roughness=0.0)
    asset = sphere_asset(0.0, 0.0)
    base = render(asset, env, opts(method=method, override=glass, pitch=10)).linear[..., :3]
    turned = render(asset, env, opts(method=method, override=glass, pitch=10, yaw=70,
                                     env_rotation=70.0)).linear[..., :3]
    env_only = render(asset, env, opts(method=method, override=glass, pitch=10,
                                       env_rotation=70.0)).linear[..., :3]
    err = np.abs(turned - base).mean()
    assert err < 0.01, err
    assert np.abs(env_only - base).mean() > 5 * err


def test_coverage_alpha_jpeg_keeps_the_background():
    """A format without alpha (JPEG) keeps the composited colour of an alpha=coverage frame
    instead of putting it onto black, as it does for a transparent one."""
    import io

    from PIL import Image

    env = make_env(gradient_radiance, size=32, key="gradient")
    o = opts(method="opaque", alpha="coverage")
    frame = render(sphere_asset(0.0, 0.5), env, o)
    jpeg = np.asarray(Image.open(io.BytesIO(frame.encode("jpeg", quality=95))).convert("RGB"), float)
    corner = frame.rgba8[:8, :8, :3].astype(float)
    assert frame.rgba8[:8, :8, 3].max() == 0 and corner.mean() > 60
    assert np.abs(jpeg[:8, :8] - corner).mean() < 4
