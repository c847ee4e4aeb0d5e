"""Time (issue 27): keyframe interpolation against hand-computed values, posed glTF and USD
scenes against numpy, --time / --animate through the CLI, the poster frame, and framing that
keeps a whole motion inside the image."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder
from PIL import Image, ImageSequence

from cli.main import main
from core.animation import Animation, Channel, Moment, poster_time, requested, sample, slerp
from core.errors import NotInAsset
from core.options import RenderOptions
from pipeline.ingest import load_scene


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return str(tmp_path_factory.mktemp("animation-cache"))


# -- interpolation, by hand --------------------------------------------------------------------

TIMES = np.array([0.0, 2.0])


def test_linear_and_step():
    v = np.array([[0.0, 10.0, -4.0], [1.0, 20.0, 4.0]])
    assert np.allclose(sample(TIMES, v, "LINEAR", 0.5), [0.25, 12.5, -2.0])
    assert np.allclose(sample(TIMES, v, "STEP", 1.99), v[0])
    assert np.allclose(sample(TIMES, v, "STEP", 2.0), v[1])
    # outside the keys the end values hold
    assert np.allclose(sample(TIMES, v, "LINEAR", -1.0), v[0])
    assert np.allclose(sample(TIMES, v, "LINEAR", 9.0), v[1])


def test_cubic_spline_uses_tangents_scaled_by_the_interval():
    # keys (in-tangent, value, out-tangent): (0, 0, 1) at t=0, (0, 1, 0) at t=2. At u = 1/2 the
    # Hermite basis is h00 = h01 = 1/2, h10 = 1/8, h11 = -1/8; tangents times dt = 2:
    # 0.5*0 + 0.125*(1*2) + 0.5*1 - 0.125*(0*2) = 0.75
    v = np.array([[[0.0], [0.0], [1.0]], [[0.0], [1.0], [0.0]]])
    assert sample(TIMES, v, "CUBICSPLINE", 1.0)[0] == pytest.approx(0.75)
    # at u = 1/4: h00 = 27/32, h10 = 9/64, h01 = 5/32, h11 = -3/64 -> 9/64*2 + 5/32 = 0.4375
    assert sample(TIMES, v, "CUBICSPLINE", 0.5)[0] == pytest.approx(0.4375)
    assert sample(TIMES, v, "CUBICSPLINE", 2.0)[0] == pytest.approx(1.0)


def test_rotation_slerps_the_short_way():
    q0 = np.array([0.0, 0.0, 0.0, 1.0])
    q90 = np.array([0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)])  # 90 deg about Z
    half = sample(TIMES, np.stack([q0, q90]), "LINEAR", 1.0, quaternion=True)
    assert np.allclose(half, [0, 0, math.sin(math.pi / 8), math.cos(math.pi / 8)])  # 45 deg
    # -q90 is the same rotation: the path must not go the long way (through 225 deg)
    assert np.allclose(slerp(q0, -q90, 0.5), half)
    # a third of the way: 30 deg, not the normalised lerp's 31.7
    third = slerp(q0, q90, 1 / 3)
    assert 2 * math.degrees(math.atan2(third[2], third[3])) == pytest.approx(30.0)


def test_poster_is_the_middle_of_the_range():
    a = Animation("walk", [Channel(0, "translation", "LINEAR", np.array([0.5, 2.5]), np.zeros((2, 3)))])
    assert poster_time(a) == 1.5 and a.duration == 2.0
    assert requested(RenderOptions()) is None
    assert requested(RenderOptions(animation="walk")) == Moment("poster", "walk")
    assert requested(RenderOptions(time="0.25")) == Moment(0.25, None)


def test_time_option_is_checked():
    with pytest.raises(ValueError, match="time"):
        RenderOptions(time="soon")
    with pytest.raises(ValueError, match="time"):
        RenderOptions(time="nan")
    with pytest.raises(ValueError, match="animate"):
        RenderOptions(animate=12, time="1")
    assert RenderOptions(time="1").key_dict() != RenderOptions(time="2").key_dict()


# -- posed glTF scenes against numpy ------------------------------------------------------------

def _animated(path: Path) -> Path:
    """A cube whose node translates (LINEAR), rotates (STEP), carries a morph target whose weight
    animates through a sparse accessor, and a second cube skinned to a joint that moves in Y."""
    b = Builder()
    delta = np.zeros_like(CUBE_POSITIONS)
    delta[:, 1] = 1.0  # the target lifts every vertex by 1
    mesh = b.mesh(CUBE_POSITIONS, CUBE_INDICES)
    b.doc["meshes"][mesh]["primitives"][0]["targets"] = [{"POSITION": b.accessor(delta)}]
    b.doc["meshes"][mesh]["weights"] = [0.0]
    cube = b.node(mesh)
    times = b.accessor(np.array([0.0, 1.0, 2.0], np.float32))
    move = b.accessor(np.array([[0, 0, 0], [4, 0, 0], [4, 0, 0]], np.float32))
    turn = b.accessor(np.array([[0, 0, 0, 1], [0, 0, 1, 0], [0, 0, 1, 0]], np.float32))
    # weights 0, 0, 0 in the buffer; the sparse part sets key 1 to 1.0
    weights = b.accessor(np.zeros(3, np.float32))
    acc = b.doc["accessors"][weights]
    acc["sparse"] = {"count": 1,
                     "indices": {"bufferView": b.view(np.array([1], np.uint8).tobytes()),
                                 "componentType": 5121},
                     "values": {"bufferView": b.view(np.array([1.0], np.float32).tobytes())}}
    # the skinned cube: one joint, node `joint`, identity inverse bind
    skinned = b.mesh(CUBE_POSITIONS + np.array([10, 0, 0], np.float32), CUBE_INDICES,
                     JOINTS_0=np.zeros((8, 4), np.uint8),
                     WEIGHTS_0=np.tile(np.array([1, 0, 0, 0], np.float32), (8, 1)))
    joint = b.node(None, translation=[0.0, 0.0, 0.0])
    b.node(skinned, skin=0)
    b.doc["skins"] = [{"joints": [joint]}]
    lift = b.accessor(np.array([[0, 0, 0], [0, 2, 0], [0, 6, 0]], np.float32))
    b.doc["animations"] = [{"name": "all", "samplers": [
        {"input": times, "output": move},
        {"input": times, "output": turn, "interpolation": "STEP"},
        {"input": times, "output": weights},
        {"input": times, "output": lift}],
        "channels": [
            {"sampler": 0, "target": {"node": cube, "path": "translation"}},
            {"sampler": 1, "target": {"node": cube, "path": "rotation"}},
            {"sampler": 2, "target": {"node": cube, "path": "weights"}},
            {"sampler": 3, "target": {"node": joint, "path": "translation"}}]}]
    return b.write(path)


def _world(scene, mesh_index: int) -> np.ndarray:
    """The mesh's distinct world-space corners, sorted (ingest splits vertices per face)."""
    inst = next(i for i in scene.instances if i.mesh == mesh_index)
    p = scene.meshes[mesh_index].positions.astype(np.float64)
    return _points(p @ inst.matrix[:3, :3].T + inst.matrix[:3, 3])


def _points(p) -> np.ndarray:
    return np.unique(np.round(np.asarray(p, np.float64), 5), axis=0)


def test_posed_nodes_morphs_and_skins_match_numpy(tmp_path):
    path = _animated(tmp_path / "anim.glb")
    rest = load_scene(path)
    assert rest.moment is None
    [summary] = rest.animations
    assert summary["name"] == "all" and summary["duration"] == 2.0 and summary["channels"] == 4
    assert {(t["path"], t["interpolation"]) for t in summary["targets"]} == {
        ("translation", "LINEAR"), ("rotation", "STEP"), ("weights", "LINEAR")}

    at = load_scene(path, moment=Moment(0.5))
    assert at.moment == {"animation": "all", "time": 0.5}
    # t = 0.5: translation lerps to (2, 0, 0); STEP holds the identity rotation; the sparse
    # weight lerps 0 -> 1 to 0.5, lifting every vertex by 0.5
    expected = CUBE_POSITIONS.astype(np.float64) + [2.0, 0.5, 0.0]
    assert np.allclose(_world(at, 0), _points(expected), atol=1e-5)
    # skinned: the joint lerps to (0, 1, 0), and the whole mesh with it
    assert np.allclose(_world(at, 1), _points(CUBE_POSITIONS + [10.0, 1.0, 0.0]), atol=1e-5)

    at = load_scene(path, moment=Moment(1.5))
    # t = 1.5: translation (4, 0, 0); STEP has switched to 180 deg about Z (x, y -> -x, -y);
    # the weight is back at 0.5 (1 -> 0); the joint at (0, 4, 0)
    lifted = CUBE_POSITIONS.astype(np.float64) + [0.0, 0.5, 0.0]
    expected = np.stack([-lifted[:, 0], -lifted[:, 1], lifted[:, 2]], axis=1) + [4.0, 0.0, 0.0]
    assert np.allclose(_world(at, 0), _points(expected), atol=1e-5)
    assert np.allclose(_world(at, 1), _points(CUBE_POSITIONS + [10.0, 4.0, 0.0]), atol=1e-5)


def test_unknown_animation_names_what_there_is(tmp_path):
    path = _animated(tmp_path / "anim.glb")
    with pytest.raises(NotInAsset, match="no animation 'run'.*'all'"):
        load_scene(path, moment=Moment(0.0, "run"))
    moment = load_scene(path, moment=Moment(0.5, "0")).moment
    assert moment is not None and moment["animation"] == "all"


def test_cesium_man_skin_against_numpy(assets):
    """The reader's skinned positions at t = 0.6 against linear blend skinning done here
    from the raw accessors with pygltflib-free numpy (joint matrices from the posed nodes)."""
    path = assets / "gltf-samples/CesiumMan/glTF-Binary/CesiumMan.glb"
    if not path.exists():
        pytest.skip("CesiumMan sample not present")
    rest, posed = load_scene(path), load_scene(path, moment=Moment(0.6))
    a, b = rest.meshes[0].positions, posed.meshes[0].positions
    assert a.shape == b.shape and np.isfinite(b).all()
    moved = np.linalg.norm(a - b, axis=1)
    assert moved.max() > 0.05  # the walk moves limbs by centimetres to decimetres
    assert not np.allclose(load_scene(path, moment=Moment(0.3)).meshes[0].positions, b)


def test_skinned_normals_follow_the_inverse_transpose_and_survive_a_zero_scaled_joint():
    """Normals under per-vertex matrices: perpendicular to the moved surface under non-uniform
    scale and a mirror (the inverse transpose, not M), and finite unit vectors where a joint is
    scaled to zero, which animators use to hide a part (np.linalg.inv raised there)."""
    from pipeline.gltf.skin import apply_skin

    rng = np.random.default_rng(7)
    shear = np.diag([3.0, 0.5, -1.0]) @ np.array([[1.0, 0.8, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    blend = np.tile(np.eye(4), (4, 1, 1))
    blend[:3, :3, :3] = shear
    blend[3, :3, :3] = 0.0  # a zero-scaled joint
    tangent = np.array([[1.0, -1.0, 0.0]] * 4, np.float32)  # in the surface: n . t = 0
    normal = np.array([[1.0, 1.0, 0.0]] * 4, np.float32) / np.sqrt(2.0)
    _, n, _ = apply_skin(blend, rng.normal(size=(4, 3)).astype(np.float32), normal, None)
    assert n is not None and np.isfinite(n).all()
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    moved_tangent = tangent[:3] @ shear.T
    assert np.allclose(np.einsum("vi,vi->v", n[:3], moved_tangent), 0.0, atol=1e-6)
    expected = normal[0] @ np.linalg.inv(shear)  # (M^-T n) as a row vector
    assert np.allclose(n[0], expected / np.linalg.norm(expected), atol=1e-6)  # same side, not flipped


# -- USD time samples ---------------------------------------------------------------------------

USDA = """#usda 1.0
(
    startTimeCode = 10
    endTimeCode = 30
    timeCodesPerSecond = 10
    metersPerUnit = 1
    upAxis = "Y"
)
def Xform "Mover"
{
    double3 xformOp:translate.timeSamples = {
        10: (0, 0, 0),
        30: (2, 0, 0),
    }
    uniform token[] xformOpOrder = ["xformOp:translate"]
    def Mesh "Tri"
    {
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    }
}
"""


def test_usd_time_sampled_xform_between_samples(tmp_path):
    path = tmp_path / "mover.usda"
    path.write_text(USDA)
    rest = load_scene(path)
    assert rest.time_range == {"start": 10.0, "end": 30.0, "time_codes_per_second": 10.0,
                               "duration": 2.0}
    assert rest.bounds[0, 0] == pytest.approx(0.0)
    # 0.5 s from the start at 10 codes per second: time code 15, a quarter of the way -> x 0.5
    at = load_scene(path, moment=Moment(0.5))
    assert at.moment == {"time_code": 15.0}
    assert at.bounds[0, 0] == pytest.approx(0.5)
    assert load_scene(path, moment=Moment("poster")).bounds[0, 0] == pytest.approx(1.0)


def _quat_matrix(q) -> np.ndarray:
    """Row-vector 3 x 3 rotation of a unit quaternion (w, x, y, z), as USD's GfQuat writes it."""
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)],
                     [2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)],
                     [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)]])


def test_usd_skel_posed_between_samples_matches_numpy_lbs(assets):
    """tests/assets/usd/skel/bending_arm.usda: the elbow turns 0 -> 90 degrees over time codes
    0 -> 10 and a blend shape lifts the hand by 0.5 m. At 0.25 s (time code 2.5, a quarter of
    the way) the elbow is at 22.5 degrees and the shape at weight 0.25: the points are the blend
    shape's, then linear blend skinning by the skeleton's joints (evaluated here in numpy from
    the file's raw bind transforms, influences and offsets), then the skeleton's translate;
    the authored normals plus the shape's normalOffsets follow the joints (inverse-transpose,
    renormalised)."""
    from pxr import Usd
    path = assets / "usd/skel/bending_arm.usda"
    stage = Usd.Stage.Open(str(path))
    mesh, skel = stage.GetPrimAtPath("/Arm/Skin"), stage.GetPrimAtPath("/Arm/Skel")
    points = np.array(mesh.GetAttribute("points").Get(), np.float64)
    normals = np.array(mesh.GetAttribute("normals").Get(), np.float64)
    index = np.array(mesh.GetAttribute("primvars:skel:jointIndices").Get()).reshape(-1, 2)
    weight = np.array(mesh.GetAttribute("primvars:skel:jointWeights").Get()).reshape(-1, 2)
    shape = stage.GetPrimAtPath("/Arm/Skin/Lift")
    offsets = np.array(shape.GetAttribute("offsets").Get(), np.float64)
    hand = list(shape.GetAttribute("pointIndices").Get())
    points[hand] += 0.25 * offsets
    normals[hand] += 0.25 * np.array(shape.GetAttribute("normalOffsets").Get(), np.float64)
    bind = [np.array(m) for m in skel.GetAttribute("bindTransforms").Get()]
    # joint locals at code 2.5: the elbow's rotation slerped a quarter of the way to 90 degrees
    half = math.radians(22.5) / 2
    elbow = np.eye(4)
    elbow[:3, :3] = _quat_matrix((math.cos(half), 0.0, 0.0, math.sin(half)))
    elbow[3, :3] = (1.0, 0.0, 0.0)
    world = [np.eye(4), elbow @ np.eye(4)]  # the elbow's parent is the shoulder (identity)
    skinning = [np.linalg.inv(b) @ w for b, w in zip(bind, world)]  # row vectors
    homogeneous = np.c_[points, np.ones(len(points))]
    expected = sum(weight[:, k, None] * np.einsum("ni,nij->nj", homogeneous,
                                                  np.stack([skinning[j] for j in index[:, k]]))
                   for k in range(2))[:, :3] + (0.0, 0.0, 2.0)
    turned = sum(weight[:, k, None] * np.einsum("ni,nij->nj", normals, np.stack(
        [np.linalg.inv(skinning[j][:3, :3]).T for j in index[:, k]])) for k in range(2))
    turned /= np.linalg.norm(turned, axis=1, keepdims=True)
    # by hand, the hand's inner corner: the elbow (1, 0) plus (1, 0.125) turned 22.5 degrees
    c, s = math.cos(math.radians(22.5)), math.sin(math.radians(22.5))
    np.testing.assert_allclose(expected[2], (1 + c - 0.125 * s, s + 0.125 * c, 2.0), atol=1e-9)

    scene = load_scene(path, moment=Moment(0.25))
    assert scene.moment == {"time_code": 2.5} and not scene.warnings
    assert scene.skel_animations == [{"path": "/Arm/Skel/Bend", "joints": 2, "blend_shapes": ["Lift"],
                                      "samples": 2, "first": 0.0, "last": 10.0}]  # for inspect
    (inst,) = scene.instances
    m = scene.meshes[inst.mesh]
    got = m.positions @ inst.matrix[:3, :3].T + inst.matrix[:3, 3]
    got_n = m.normals @ inst.matrix[:3, :3].T
    assert len(got) == len(expected)
    for p, n in zip(got, got_n):  # ingest may reorder vertices: match each to its point
        k = int(np.argmin(np.linalg.norm(expected - p, axis=1)))
        np.testing.assert_allclose(p, expected[k], atol=1e-5)
        np.testing.assert_allclose(n, turned[k], atol=1e-5)
    # at the start the arm is straight and flat: the skin is the bind pose itself
    rest = load_scene(path, moment=Moment(0.0))
    r = rest.meshes[rest.instances[0].mesh]
    assert r.positions[:, 1].max() == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(r.normals @ rest.instances[0].matrix[:3, :3].T,
                               np.tile((0.0, 1.0, 0.0), (len(r.normals), 1)), atol=1e-6)


def test_usd_skel_face_varying_normals_follow_their_points(assets, tmp_path):
    """The same arm with its normals authored per face-vertex (indexed): each is skinned by
    its point's influences; at code 10 the elbow is at 90 degrees, so the hand's normals
    (all on the elbow joint) turn from +Y to -X, the shoulder's stay +Y. The blend shape's
    normalOffsets apply to vertex normals only (as UsdSkel has it): not to these."""
    text = (assets / "usd/skel/bending_arm.usda").read_text()
    vertex = text[text.index("        normal3f[] normals"):text.index("        int[] primvars:skel:jointIndices")]
    face_varying = """        normal3f[] primvars:normals = [(0, 1, 0)] (
            interpolation = "faceVarying"
        )
        int[] primvars:normals:indices = [0, 0, 0, 0, 0, 0, 0, 0]
"""
    path = tmp_path / "arm.usda"
    path.write_text(text.replace(vertex, face_varying))
    scene = load_scene(path, moment=Moment(1.0))
    assert not scene.warnings
    (inst,) = scene.instances
    m = scene.meshes[inst.mesh]
    p = m.positions @ inst.matrix[:3, :3].T + inst.matrix[:3, 3]
    n = m.normals @ inst.matrix[:3, :3].T
    hand = p[:, 1] > 0.9  # bound at x = 2, lifted 0.5, turned about the elbow: (0.5, 1)
    shoulder = np.isclose(p[:, 0], 0.0, atol=1e-6)
    assert hand.sum() == 2 and shoulder.sum() == 2
    np.testing.assert_allclose(n[hand], [[-1.0, 0.0, 0.0]] * 2, atol=1e-6)
    np.testing.assert_allclose(n[shoulder], [[0.0, 1.0, 0.0]] * 2, atol=1e-6)


CAMERA_AND_LIGHT = """#usda 1.0
(
    startTimeCode = 0
    endTimeCode = 10
    timeCodesPerSecond = 10
    metersPerUnit = 1
    upAxis = "Y"
)
def Xform "World"
{
    def Camera "Shot"
    {
        float focalLength.timeSamples = { 0: 50, 10: 25 }
        float verticalAperture = 24
        float2 clippingRange = (0.1, 100)
        double3 xformOp:translate.timeSamples = { 0: (0, 0, 10), 10: (4, 0, 10) }
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def DistantLight "Sun"
    {
        float inputs:angle = 0
        float inputs:intensity.timeSamples = { 0: 1, 10: 3 }
        color3f inputs:color.timeSamples = { 0: (1, 0, 0), 10: (0, 0, 1) }
        float xformOp:rotateY.timeSamples = { 0: 0, 10: 90 }
        uniform token[] xformOpOrder = ["xformOp:rotateY"]
    }
    def Mesh "Floor"
    {
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 0, -1)]
    }
}
"""


def test_usd_camera_and_light_attributes_between_samples(tmp_path):
    """A camera's focal length and translate and a light's intensity, colour and rotation
    are read at the moment's time code: 0.25 s is code 2.5, a quarter of the way, so the
    focal length is 50 - 25 / 4 = 43.75 mm (vertical field of view 2 atan(12 / 43.75)), the
    camera at x = 1, the light's intensity 1.5, its colour (0.75, 0, 0.25), and it is turned
    22.5 degrees about +Y (it shines down its -Z: towards (-sin, 0, -cos))."""
    path = tmp_path / "shot.usda"
    path.write_text(CAMERA_AND_LIGHT)
    scene = load_scene(path, moment=Moment(0.25))
    (cam,) = scene.cameras
    assert cam.yfov == pytest.approx(2 * math.atan(12 / 43.75), rel=1e-6)
    np.testing.assert_allclose(cam.matrix[:3, 3], (1.0, 0.0, 10.0), atol=1e-9)
    (sun,) = scene.lights
    assert sun.type == "directional" and sun.intensity == pytest.approx(1.5)
    np.testing.assert_allclose(sun.color, (0.75, 0.0, 0.25), atol=1e-6)
    a = math.radians(22.5)
    np.testing.assert_allclose(-sun.matrix[:3, 2], (-math.sin(a), 0.0, -math.cos(a)), atol=1e-6)
    # the start, for contrast: the authored first samples
    start = load_scene(path)
    assert start.cameras[0].yfov == pytest.approx(2 * math.atan(12 / 50), rel=1e-6)
    assert start.lights[0].intensity == pytest.approx(1.0)
    np.testing.assert_allclose(start.lights[0].color, (1.0, 0.0, 0.0), atol=1e-6)


# -- the CLI: --time, poster, --animate ---------------------------------------------------------

def _sample(assets: Path, name: str) -> Path:
    path = assets / f"gltf-samples/{name}/glTF-Binary/{name}.glb"
    if not path.exists():
        pytest.skip(f"{name} sample not present")
    return path


def test_time_changes_pixels_and_poster_is_deterministic(assets, cache, tmp_path):
    path = _sample(assets, "CesiumMan")
    images = {}
    for label, extra in (("rest", []), ("t0.3", ["--time", "0.3"]), ("poster", ["--time", "poster"]),
                         ("poster2", ["--time", "poster"])):
        out = tmp_path / f"{label}.png"
        assert main(["render", str(path), "--out", str(out), "--size", "96", "--cache", cache,
                     *extra]) == 0
        images[label] = np.asarray(Image.open(out)).astype(int)
    assert np.abs(images["rest"] - images["t0.3"]).max() > 64
    assert np.abs(images["t0.3"] - images["poster"]).max() > 64
    assert np.array_equal(images["poster"], images["poster2"])
    from pipeline.bake import bake_asset
    keys = {bake_asset(path, cache, moment=m).key for m in (None, Moment(0.3), Moment("poster"))}
    assert len(keys) == 3


@pytest.mark.parametrize("name, animation, fps", [("CesiumMan", None, 6), ("Fox", "Survey", 3)])
def test_whole_motion_stays_in_frame(assets, cache, tmp_path, name, animation, fps):
    path = _sample(assets, name)
    out = tmp_path / f"{name}.webp"
    args = ["render", str(path), "--out", str(out), "--size", "64", "--cache", cache,
            "--background", "transparent", "--shadow", "0", "--animate", str(fps)]
    assert main(args + (["--animation", animation] if animation else [])) == 0
    frames = [np.asarray(f.convert("RGBA")) for f in ImageSequence.Iterator(Image.open(out))]
    assert len(frames) >= 6
    for f in frames:
        alpha = f[..., 3]
        assert alpha.max() == 255  # the asset is there
        border = np.concatenate([alpha[0], alpha[-1], alpha[:, 0], alpha[:, -1]])
        assert border.max() < 128, "the motion leaves the frame"
    assert any(np.abs(frames[0].astype(int) - f.astype(int)).max() > 64 for f in frames[1:])


def test_animate_with_turntable_as_apng(assets, cache, tmp_path):
    path = _sample(assets, "CesiumMan")
    out = tmp_path / "cm.png"
    assert main(["render", str(path), "--out", str(out), "--size", "48", "--cache", cache,
                 "--animate", "4", "--turntable", "8"]) == 0
    im = Image.open(out)
    assert getattr(im, "n_frames", 1) == 8  # 1.96 s at 4 fps


def test_usd_animate_through_its_animated_camera(cache, tmp_path):
    """--animate --camera PRIM on a stage whose camera dollies and zooms out and whose only
    light turns from red to blue: each frame is seen through the camera at its own time code
    (nothing else moves), so the triangle shifts left, shrinks, and its red falls."""
    path = tmp_path / "shot.usda"
    path.write_text(CAMERA_AND_LIGHT.replace("(0, 0, 0), (1, 0, 0), (0, 0, -1)",
                                             "(-1, -1, 0), (1, -1, 0), (0, 1, 0)"))
    out = tmp_path / "shot.png"
    assert main(["render", str(path), "--out", str(out), "--size", "64", "--cache", cache,
                 "--camera", "/World/Shot", "--animate", "2"]) == 0
    frames = [np.asarray(f.convert("RGB"), np.int32) for f in ImageSequence.Iterator(Image.open(out))]
    assert len(frames) == 2  # 0 and 0.5 s of the 1 s range
    covered = [(f.max(axis=2) - f.min(axis=2)) > 40 for f in frames]  # the coloured triangle
    cols = [np.nonzero(c.any(axis=0))[0] for c in covered]
    assert covered[1].sum() < 0.8 * covered[0].sum()  # focal length 50 -> 37.5 mm
    assert cols[1].mean() < cols[0].mean() - 2  # the camera moved +x: the triangle left
    red = [f[c][:, 0].mean() for f, c in zip(frames, covered)]
    assert red[1] < red[0]


def test_animate_needs_an_animation(assets, cache, tmp_path, capsys):
    out = tmp_path / "box.webp"
    assert main(["render", str(assets / "gltf/BoxTextured.glb"), "--out", str(out), "--size", "32",
                 "--cache", cache, "--animate", "4"]) == 3  # an AssetError (cli.main)
    assert "no animation" in capsys.readouterr().err


def test_time_and_animate_over_http(server, assets):
    import io
    import json

    from test_service import upload
    path = _sample(assets, "CesiumMan")
    r = upload(server, "CesiumMan.glb", path.read_bytes())
    assert r.status_code == 201, r.text
    rec = server.wait_status(r.json()["id"])
    assert rec["status"] == "ready", rec
    url = f"/assets/{rec['id']}/thumbnail"
    r = server.client.get(url, params={"size": 48, "animate": 4, "format": "webp"})
    assert r.status_code == 200 and r.headers["content-type"] == "image/webp", r.text
    im = Image.open(io.BytesIO(r.content))
    assert getattr(im, "n_frames", 1) == 8 and im.size == (48, 48)
    plan = json.loads(r.headers["x-render-plan"])
    assert plan["animate"]["frames"] == 8 and plan["animate"]["fps"] == 4
    stills = [server.client.get(url, params={"size": 48, **p}) for p in ({}, {"time": "0.6"})]
    assert all(s.status_code == 200 for s in stills)
    assert stills[0].content != stills[1].content and stills[0].headers["etag"] != stills[1].headers["etag"]
    r = server.client.get(url, params={"size": 48, "animate": 4, "format": "jpeg"})
    assert r.status_code == 422 and "webp, gif or png" in r.json()["detail"]


def test_worker_renders_time_and_animate(assets, tmp_path):
    """The service's worker job (what the HTTP test above reaches through a server): posed
    from the bake's source, the animation encoded in the format asked for."""
    import io

    from service.workers.jobs import WorkerState
    from service.workers.protocol import BakeJob, RenderJob, WorkerConfig
    path = _sample(assets, "CesiumMan")
    state = WorkerState(WorkerConfig(cache_dir=str(tmp_path / "cache"), default_env="studio"))
    key = state.bake(BakeJob(str(path))).key
    out = state.render(RenderJob(key, "studio", RenderOptions(width=40, height=40, animate=4), "webp"))
    im = Image.open(io.BytesIO(out.image))
    assert getattr(im, "n_frames", 1) == 8 and out.plan.details["animate"]["frames"] == 8
    rest, moved = (state.render(RenderJob(key, "studio", RenderOptions(width=40, height=40, time=t), "png"))
                   for t in (None, "0.6"))
    assert rest.image != moved.image


def test_inspect_json_lists_animations_and_time_range(tmp_path, capsys):
    import json
    gltf = _animated(tmp_path / "anim.glb")
    assert main(["inspect", "--json", str(gltf)]) == 0
    info = json.loads(capsys.readouterr().out)
    [anim] = info["animations"]
    assert anim["name"] == "all" and anim["duration"] == 2.0 and anim["channels"] == 4
    assert {t["path"] for t in anim["targets"]} == {"translation", "rotation", "weights"}
    assert info["time_range"] is None
    usd = tmp_path / "mover.usda"
    usd.write_text(USDA)
    assert main(["inspect", "--json", str(usd)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["animations"] == [] and info["time_range"]["time_codes_per_second"] == 10.0
