"""USD lights with extent in the ray tracer (renderer/methods/trace_lights.py, issue 25): the
tree and path integrators sample a rect / disk / sphere / cylinder light's points and a
distant light's cone, so shadows have penumbrae, with the punctual light's radiometry on
receivers that see the whole light."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from core.options import RenderOptions
from core.scene import Light
from pipeline.bake import bake_environment, build_baked
from pipeline.environment import uniform
from pipeline.ingest import load_scene
from renderer import render
from renderer.methods import trace_lights
from renderer.view.framing import asset_camera

GRID = 64  # 64 x 64 stratified samples of each light for the irradiance checks
IRRADIANCE_TOLERANCE = 0.01


def _down(position) -> np.ndarray:
    """A light matrix at `position` whose -Z (emitting side) points down -Y, x along +X."""
    m = np.eye(4)
    m[:3, 1] = (0.0, 0.0, -1.0)
    m[:3, 2] = (0.0, 1.0, 0.0)
    m[:3, 3] = position
    return m


def _irradiance(light: Light, p: np.ndarray, n: np.ndarray, samples: bool) -> np.ndarray:
    """Irradiance at points p (normals n) from `light` through trace_lights.direct on a white
    Lambert surface (no specular: radiance x pi), unoccluded; `samples`: over its extent."""
    lights = trace_lights.lights_of([light])
    u = (np.arange(GRID) + 0.5) / GRID
    draws = [(np.full(len(p), a), np.full(len(p), b)) for a in u for b in u] if samples else None

    def no_spec(f0, cos_v, rough):
        return np.zeros_like(f0), np.zeros_like(f0)

    ones = np.ones(len(p))
    out = trace_lights.direct(lights, lambda o, d, t, nn: np.ones((len(o), 3)), p, n, n,
                              n, np.ones((len(p), 3)), 0 * ones, ones, 0 * ones, 1.5 * ones,
                              no_spec, None, draws)
    return out[:, 0] * math.pi


def _receivers(height: float, spread: float) -> tuple[np.ndarray, np.ndarray]:
    """Points on the ground y = 0 about the origin, facing up, `height` below the light."""
    xs = np.linspace(-spread, spread, 5)
    p = np.array([(x, 0.0, z) for x in xs for z in xs])
    return p, np.tile([0.0, 1.0, 0.0], (len(p), 1))


def _spot_light(shape: str, size, height: float) -> Light:
    return Light(type="spot", intensity=7.0, inner_cone=0.0, outer_cone=math.pi / 2,
                 matrix=_down((0.0, height, 0.0)), shape=shape, size=size)


@pytest.mark.parametrize("light", [
    _spot_light("rect", (0.6, 0.4), 8.0),
    _spot_light("disk", (0.3, 0.3), 8.0),
    Light(type="point", intensity=7.0, matrix=_down((0.0, 8.0, 0.0)), shape="cylinder", size=(0.1, 0.6)),
    Light(type="point", intensity=7.0, matrix=_down((0.0, 8.0, 0.0)), shape="cylinder", size=(0.0, 0.6)),
], ids=["rect", "disk", "cylinder", "line"])
def test_far_receivers_get_the_punctual_lights_irradiance(light):
    """A receiver over ten times the light's size away sees the point light's irradiance (a
    cylinder's: as much as broadside, less toward its axis, as its projected area)."""
    p, n = _receivers(8.0, 3.0)
    point = _irradiance(light, p, n, False)
    sampled = _irradiance(light, p, n, True)
    assert point.min() > 0
    if light.shape == "cylinder":  # its projected area goes as the sine from its axis (x)
        point = point * np.sqrt(1.0 - p[:, 0] ** 2 / np.einsum("ij,ij->i", p - (0, 8, 0), p - (0, 8, 0)))
    assert np.allclose(sampled, point, rtol=IRRADIANCE_TOLERANCE), np.max(np.abs(sampled / point - 1))


@pytest.mark.parametrize("height", [1.2, 3.0])
def test_sphere_light_irradiance_is_the_point_lights_at_any_distance(height):
    """A sphere of uniform radiance seen whole above the horizon gives exactly I cos / d^2
    (the projected solid angle of its cap), near as well as far."""
    light = Light(type="point", intensity=7.0, matrix=_down((0.0, height, 0.0)), shape="sphere",
                  size=(0.5, 0.0))
    p, n = _receivers(height, 0.6)
    point, sampled = _irradiance(light, p, n, False), _irradiance(light, p, n, True)
    assert np.allclose(sampled, point, rtol=IRRADIANCE_TOLERANCE), np.max(np.abs(sampled / point - 1))


@pytest.mark.parametrize("angle", [0.53, 10.0, 40.0])
def test_distant_light_cone_keeps_the_directional_illuminance(angle):
    """A cap of half-angle t fully above the horizon: its projected solid angle is
    pi sin^2 t cos(elevation), so E cos is unchanged."""
    m = np.eye(4)
    tilt = math.radians(35.0)  # from the zenith
    m[:3, 2] = (math.sin(tilt), math.cos(tilt), 0.0)  # toward the light
    m[:3, 1] = (math.cos(tilt), -math.sin(tilt), 0.0)
    m[:3, 0] = np.cross(m[:3, 1], m[:3, 2])
    light = Light(type="directional", intensity=3.0, matrix=m, shape="cone",
                  size=(math.radians(angle) / 2, 0.0))
    p, n = _receivers(1.0, 1.0)
    point, sampled = _irradiance(light, p, n, False), _irradiance(light, p, n, True)
    assert np.allclose(point, 3.0 * math.cos(tilt))
    assert np.allclose(sampled, point, rtol=IRRADIANCE_TOLERANCE)


def test_near_rect_light_irradiance_is_its_area_integral():
    """Near a rect light, each of its points emits with the light's profile (a 90 degree
    spot's cos^2 and inverse square, as the punctual light): the sampled irradiance is that
    integral over the area (midpoint rule, 400 x 400 cells), within 1%."""
    w, h, height = 1.5, 1.0, 1.2
    light = _spot_light("rect", (w, h), height)
    p, n = _receivers(height, 1.5)
    sampled = _irradiance(light, p, n, True)
    cells = 400
    xs = ((np.arange(cells) + 0.5) / cells - 0.5) * w
    zs = ((np.arange(cells) + 0.5) / cells - 0.5) * h
    qx, qz = np.meshgrid(xs, -zs)  # the light's y axis is world -Z
    expected = []
    for x, _, z in p:
        dx, dz = qx - x, qz - z
        r2 = dx * dx + dz * dz + height * height
        cos = height / np.sqrt(r2)  # at the light (its axis is down) and at the receiver alike
        expected.append(float(np.mean(light.intensity * cos * cos / r2 * cos)))
    assert np.allclose(sampled, expected, rtol=IRRADIANCE_TOLERANCE), np.max(np.abs(sampled / expected - 1))
    # and it is not the point light's there: the extent is what moved it
    assert np.max(np.abs(_irradiance(light, p, n, False) / expected - 1)) > 0.05


# --- penumbra width: a long wall on a ground plane, seen from above -----------------------
WALL_TOP = 0.8   # h
WALL_X = 0.05    # the wall's far face (x); its top edge casts the shadow's boundary
LIGHT_X, LIGHT_H, LIGHT_W = -1.2, 2.6, 1.5  # the rect light's centre (x, height) and width
STAGE = """#usda 1.0
(
    defaultPrim = "World"
    upAxis = "Y"
    metersPerUnit = 1
)
def Xform "World"
{
    WALL
    def Mesh "Ground"
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)]
        normal3f[] normals = [(0,1,0),(0,1,0),(0,1,0),(0,1,0)] ( interpolation = "vertex" )
        color3f[] primvars:displayColor = [(0.8, 0.8, 0.8)]
    }
    LIGHT
}
"""
WALL = """def Cube "Wall"
    {
        double size = 1
        double3 xformOp:translate = (0, %s, 0)
        float3 xformOp:scale = (%s, %s, 3.6)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
        color3f[] primvars:displayColor = [(0.8, 0.8, 0.8)]
    }""" % (WALL_TOP / 2, 2 * WALL_X, WALL_TOP)
RECT = """def RectLight "Light"
    {
        bool inputs:normalize = 1
        float inputs:intensity = 10
        float inputs:width = %s
        float inputs:height = 1.5
        double3 xformOp:translate = (%s, %s, 0)
        float3 xformOp:rotateXYZ = (-90, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }""" % (LIGHT_W, LIGHT_X, LIGHT_H)
SUN_ANGLE, SUN_TILT = 20.0, 30.0  # degrees: the cone's full angle, the light's tilt from the zenith
SUN = """def DistantLight "Light"
    {
        bool inputs:normalize = 1
        float inputs:intensity = 3
        float inputs:angle = %s
        float3 xformOp:rotateXYZ = (-90, 0, %s)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }""" % (SUN_ANGLE, SUN_TILT)
SIZE = 128
# The 5% and 95% crossings of the visible fraction against the geometric penumbra: their span
# is 0.9 of its width for the rect (uniform across it: a linear ramp) and 0.8 for the distant
# light's disc (a circular segment's area passes 5% and 95% at +-0.80 of the radius), within
# 10%; their centre within two pixels. Direct light only (one bounce), so that what the wall
# reflects onto the ground does not lift the shadow.
SPAN = {True: 0.9, False: 0.8}
WIDTH_TOLERANCE = 0.10


def _penumbra(rect: bool) -> tuple[float, float]:
    """(start, end) on the ground (x) of the shadow's penumbra by similar triangles."""
    if rect:
        slope = WALL_TOP / (LIGHT_H - WALL_TOP)
        return (WALL_X + (WALL_X - (LIGHT_X + LIGHT_W / 2)) * slope,
                WALL_X + (WALL_X - (LIGHT_X - LIGHT_W / 2)) * slope)
    tilt, half = math.radians(SUN_TILT), math.radians(SUN_ANGLE) / 2
    return WALL_X + WALL_TOP * math.tan(tilt - half), WALL_X + WALL_TOP * math.tan(tilt + half)


@pytest.fixture(scope="module")
def dark(tmp_path_factory):
    return bake_environment(uniform.name((0.0, 0.0, 0.0)), tmp_path_factory.mktemp("dark"), face_size=16)


def _ground_visibility(tmp_path, env, light: str, options: RenderOptions, hard: bool = False):
    """(x, visible fraction of the light) along the ground beside the wall: the frame with
    the wall over the frame without it, averaged over a strip |z| < 0.3."""
    frames = []
    for wall in (True, False):
        path = tmp_path / f"{'wall' if wall else 'open'}.usda"
        path.write_text(STAGE.replace("WALL", WALL if wall else "").replace("LIGHT", light))
        asset = build_baked(load_scene(path), key=f"penumbra-{path}-{hash(light)}")
        if hard:
            asset = dataclasses.replace(asset, lights=[dataclasses.replace(li, shape="") for li in asset.lights])
        frames.append((render(asset, env, options), asset_camera(asset, options)[0]))
    xs = np.linspace(WALL_X + 0.05, 1.5, 120)
    vis = []
    for x in xs:  # (a 3-sample running mean below smooths the path integrator's noise)
        got = []
        for frame, camera in frames:
            vals = []
            for z in np.linspace(-0.3, 0.3, 9):
                clip = camera.projection_matrix() @ camera.view_matrix() @ np.array([x, 0.0, z, 1.0])
                ndc = clip[:3] / clip[3]
                col = int((ndc[0] * 0.5 + 0.5) * options.width)
                row = int((0.5 - ndc[1] * 0.5) * options.height)
                vals.append(frame.linear[row, col, :3].mean())
            got.append(np.mean(vals))
        vis.append(got[0] / max(got[1], 1e-9))
    vis = np.convolve(np.pad(vis, 1, mode="edge"), np.ones(3) / 3, mode="valid")
    return xs, vis


def _crossing(xs, vis, level) -> float:
    """The first x at which the visible fraction rises through `level` (linear between)."""
    i = int(np.flatnonzero(vis >= level)[0])
    return float(xs[i - 1] + (xs[i] - xs[i - 1]) * (level - vis[i - 1]) / (vis[i] - vis[i - 1]))


@pytest.mark.parametrize("integrator", ["tree", "path"])
@pytest.mark.parametrize("rect", [True, False], ids=["rect", "distant"])
def test_penumbra_width_matches_similar_triangles(tmp_path, dark, integrator, rect):
    options = RenderOptions(width=SIZE, height=SIZE, tonemap="none", background="transparent",
                            shadow=0.0, yaw=0.0, pitch=89.0, method="raytrace", integrator=integrator,
                            samples=32, noise=0.0, bounces=1)
    xs, vis = _ground_visibility(tmp_path, dark, RECT if rect else SUN, options)
    start, end = _penumbra(rect)
    assert vis[xs < start - 0.05].max() < 0.05 and vis[xs > end + 0.05].min() > 0.95
    lo, hi = _crossing(xs, vis, 0.05), _crossing(xs, vis, 0.95)
    pixel = 4.0 / SIZE
    print(f"penumbra {integrator} {'rect' if rect else 'distant'}: 5-95% {lo:.3f}..{hi:.3f} m, "
          f"similar triangles {start:.3f}..{end:.3f} m")
    assert hi - lo == pytest.approx(SPAN[rect] * (end - start), rel=WIDTH_TOLERANCE), (lo, hi, start, end)
    assert (lo + hi) / 2 == pytest.approx((start + end) / 2, abs=2 * pixel), (lo, hi, start, end)


def test_without_the_extent_the_shadow_is_hard(tmp_path, dark):
    """The same light as a point (today's raster, and the tracers before): no penumbra."""
    options = RenderOptions(width=SIZE, height=SIZE, tonemap="none", background="transparent",
                            shadow=0.0, yaw=0.0, pitch=89.0, method="raytrace")
    xs, vis = _ground_visibility(tmp_path, dark, RECT, options, hard=True)
    lo, hi = _crossing(xs, vis, 0.05), _crossing(xs, vis, 0.95)
    assert hi - lo < 3 * 4.0 / SIZE


def test_stage_lights_keep_their_extent_in_metres(tmp_path):
    """The reader keeps each USD light's extent in metres (metersPerUnit and the xform's
    scale), a distant light's half-angle, and none for treatAsPoint; a CylinderLight is read
    (radiance x its broadside projected area 2 r l)."""
    path = tmp_path / "cm.usda"
    path.write_text("""#usda 1.0
(
    metersPerUnit = 0.01
)
def Cube "Box"
{
}
def RectLight "Panel"
{
    float inputs:width = 200
    float inputs:height = 50
}
def DiskLight "Disk"
{
    float inputs:radius = 20
    double3 xformOp:scale = (2, 1, 1)
    uniform token[] xformOpOrder = ["xformOp:scale"]
}
def SphereLight "Bulb"
{
    float inputs:radius = 10
}
def SphereLight "Point"
{
    float inputs:radius = 10
    bool treatAsPoint = 1
}
def CylinderLight "Tube"
{
    float inputs:radius = 5
    float inputs:length = 100
    float inputs:intensity = 2
}
def DistantLight "Sun"
{
    float inputs:angle = 10
}
""")
    panel, disk, bulb, point, tube, sun = load_scene(path).lights
    assert (panel.shape, panel.size) == ("rect", pytest.approx((2.0, 0.5)))
    assert (disk.shape, disk.size) == ("disk", pytest.approx((0.4, 0.2)))
    assert (bulb.shape, bulb.size) == ("sphere", pytest.approx((0.1, 0.0)))
    assert point.shape == ""
    assert (tube.shape, tube.size, tube.type) == ("cylinder", pytest.approx((0.05, 1.0)), "point")
    assert tube.intensity == pytest.approx(2 * 2 * 0.05 * 1.0)
    assert (sun.shape, sun.size) == ("cone", pytest.approx((math.radians(5.0), 0.0)))
    baked = build_baked(load_scene(path), key="extent-cm")
    assert [li.shape for li in baked.lights] == ["rect", "disk", "sphere", "", "cylinder", "cone"]
