"""The glTF node graph: the default scene's roots, local and world matrices (the graph checked
to be a tree, within `Limits.max_nodes`), skins' joint matrices, EXT_mesh_gpu_instancing,
cameras and KHR_lights_punctual lights."""
from __future__ import annotations

import math

import numpy as np

from core.errors import LimitExceeded
from core.scene import Light, SceneCamera
from pipeline import deadline
from pipeline.gltf.accessors import Document


class NodeGraph:
    """Matrices of a document's nodes; a node's parent chain is built when first needed."""

    def __init__(self, d: Document):
        self.d = d
        self._parents: dict[int, int] | None = None  # node -> parent
        self.pose: dict[int, dict[str, np.ndarray]] = {}  # node -> animated TRS / weights

    def roots(self) -> list:
        """The default scene's root nodes (every unparented node when there are no scenes)."""
        d = self.d
        scenes = d.array(d.doc, "scenes")
        if scenes:
            index = d.doc.get("scene", 0)
            return d.array(d.item("scenes", index, "default scene"), "nodes")
        nodes = d.array(d.doc, "nodes")
        children = {c for n in nodes if isinstance(n, dict) for c in n.get("children", [])
                    if isinstance(c, int)}
        return [i for i in range(len(nodes)) if i not in children]

    def local(self, node: dict, index: int) -> np.ndarray:
        """A node's matrix, from `matrix` or translation, rotation and scale."""
        d = self.d
        if index in self.pose:  # animated (core.animation): the channels' values replace its own
            node = {k: v for k, v in node.items() if k != "matrix"}
            node.update({k: [float(x) for x in v] for k, v in self.pose[index].items()})
        if "matrix" in node:
            m = np.array(d.numbers(node, "matrix", (0.0,) * 16), np.float64)
            return m.reshape(4, 4).T  # glTF stores column-major
        t = d.numbers(node, "translation", (0.0, 0.0, 0.0))
        x, y, z, w = d.numbers(node, "rotation", (0.0, 0.0, 0.0, 1.0))
        s = d.numbers(node, "scale", (1.0, 1.0, 1.0))
        norm = math.sqrt(x * x + y * y + z * z + w * w)
        if norm == 0.0:
            raise d.bad(f"node {index}: rotation quaternion is zero")
        x, y, z, w = x / norm, y / norm, z / norm, w / norm
        r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        m = np.eye(4)
        m[:3, :3] = r * np.array(s)
        m[:3, 3] = t
        return m

    def world_matrices(self) -> list[tuple[int, np.ndarray]]:
        """(node, world matrix) for every node of the default scene, parents before children;
        the node graph checked to be a tree."""
        d = self.d
        out, seen = [], set()
        stack = [(r, np.eye(4)) for r in reversed(self.roots())]
        while stack:
            deadline.check()
            index, parent = stack.pop()
            node = d.item("nodes", index, "node")
            if index in seen:
                raise d.bad(f"node {index} is reached twice: the node graph is not a tree")
            seen.add(index)
            if len(seen) > d.limits.max_nodes:
                raise LimitExceeded(d.path, f"more than {d.limits.max_nodes} nodes")
            world = parent @ self.local(node, index)
            out.append((index, world))
            for child in reversed(d.array(node, "children")):
                stack.append((child, world))
        return out

    def world_of(self, index: int, worlds: dict[int, np.ndarray]) -> np.ndarray:
        """World matrix of node `index`, also for a node outside the default scene (a skin's
        joints may be): composed down its parent chain, which is remembered in `worlds`."""
        d = self.d
        nodes = d.array(d.doc, "nodes")
        if self._parents is None:
            self._parents = {c: i for i, n in enumerate(nodes) if isinstance(n, dict)
                             for c in n.get("children", []) if isinstance(c, int)}
        chain, j = [], index
        while j not in worlds:
            chain.append(j)
            if len(chain) > len(nodes):
                raise d.bad("node hierarchy has a cycle")
            if j not in self._parents:
                break
            j = self._parents[j]
        m = worlds[j] if j in worlds else np.eye(4)
        for node in reversed(chain):
            m = m @ self.local(d.item("nodes", node, "node"), node)
            worlds[node] = m
        return worlds[index]

    def joint_matrices(self, skin_index: int, worlds: dict) -> np.ndarray:
        """J_i = world(joint_i) @ inverseBindMatrix_i for skin `skin_index` (K x 4 x 4)."""
        d = self.d
        skin = d.item("skins", skin_index, "skin")
        joints = d.array(skin, "joints")
        if not joints or len(joints) > d.limits.max_nodes:
            raise d.bad(f"skin {skin_index} has {len(joints)} joints")
        if "inverseBindMatrices" in skin:
            ibm = d.accessor(skin["inverseBindMatrices"], len(joints), f"skin {skin_index} IBM")
            if ibm.shape != (len(joints), 16) or ibm.dtype != np.float32:
                raise d.bad(f"skin {skin_index}: inverseBindMatrices is not {len(joints)} MAT4")
            ibm = ibm.astype(np.float64).reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
        else:
            ibm = np.broadcast_to(np.eye(4), (len(joints), 4, 4))
        out = np.empty((len(joints), 4, 4))
        for k, j in enumerate(joints):
            d.item("nodes", j, f"skin {skin_index} joint")
            out[k] = self.world_of(j, worlds) @ ibm[k]
        return out

    def instancing(self, node: dict, index: int, world: np.ndarray) -> np.ndarray:
        """World matrices of a node's EXT_mesh_gpu_instancing instances (K x 4 x 4), or its
        own world matrix alone."""
        d = self.d
        ext = d.obj(node.get("extensions"), f"node {index} extensions")
        spec = ext.get("EXT_mesh_gpu_instancing")
        if spec is None:
            return world[None]
        attrs = d.obj(d.obj(spec, "EXT_mesh_gpu_instancing").get("attributes"),
                      f"node {index} instancing attributes")
        what = f"node {index} EXT_mesh_gpu_instancing"
        arrays = {k: d.accessor(attrs[k], d.limits.max_nodes, f"{what} {k}")
                  for k in ("TRANSLATION", "ROTATION", "SCALE") if k in attrs}
        counts = {len(a) for a in arrays.values()}
        if len(counts) != 1:
            raise d.bad(f"{what}: attributes missing or of different counts {sorted(counts)}")
        count = counts.pop()
        t = arrays.get("TRANSLATION", np.zeros((count, 3)))
        q = arrays.get("ROTATION", np.tile([0.0, 0.0, 0.0, 1.0], (count, 1)))
        k = arrays.get("SCALE", np.ones((count, 3)))
        if t.shape[1] != 3 or q.shape[1] != 4 or k.shape[1] != 3:
            raise d.bad(f"{what}: TRANSLATION/SCALE must be VEC3 and ROTATION VEC4")
        return world @ trs(t.astype(np.float64), q.astype(np.float64), k.astype(np.float64))


def light(d: Document, index: object, matrix: np.ndarray) -> Light:
    """KHR_lights_punctual light `index` (from the JSON: checked here) placed at `matrix`."""
    lights = d.array(d.obj(d.obj(d.doc.get("extensions"), "extensions")
                           .get("KHR_lights_punctual"), "KHR_lights_punctual"), "lights")
    if not isinstance(index, int) or not 0 <= index < len(lights):
        raise d.bad(f"KHR_lights_punctual light index {index!r} out of range")
    spec = d.obj(lights[index], f"light {index}")
    kind = spec.get("type")
    if kind not in ("directional", "point", "spot"):
        raise d.bad(f"light {index}: unknown type {kind!r}")
    spot = d.obj(spec.get("spot"), f"light {index} spot")
    return Light(type=kind, color=d.numbers(spec, "color", (1.0, 1.0, 1.0)),
                 intensity=d.number(spec, "intensity", 1.0, 0.0),
                 range=d.number(spec, "range", math.inf),
                 inner_cone=d.number(spot, "innerConeAngle", 0.0),
                 outer_cone=d.number(spot, "outerConeAngle", math.pi / 4), matrix=matrix)


def camera(d: Document, index: int, node: int, world: np.ndarray) -> SceneCamera:
    """Camera `index`, on node `node` at `world`."""
    spec = d.item("cameras", index, f"node {node} camera")
    kind = spec.get("type")
    if kind not in ("perspective", "orthographic"):
        raise d.bad(f"camera {index}: type {kind!r} is not perspective or orthographic")
    p = d.obj(spec.get(kind), f"camera {index} {kind}")
    name = str(spec.get("name") or d.array(d.doc, "nodes")[node].get("name") or f"camera{index}")
    out = SceneCamera(name=name, type=kind, matrix=world,
                      znear=d.number(p, "znear", 0.01, 0.0),
                      zfar=d.number(p, "zfar", math.inf, 0.0))
    if kind == "perspective":
        out.yfov = d.number(p, "yfov", 0.8, 1e-4, math.pi - 1e-4)
        aspect = p.get("aspectRatio")
        out.aspect = None if aspect is None else d.number(p, "aspectRatio", 1.0, 1e-4)
    else:
        out.xmag = abs(d.number(p, "xmag", 1.0)) or 1.0
        out.ymag = abs(d.number(p, "ymag", 1.0)) or 1.0
    return out


def trs(t: np.ndarray, q: np.ndarray, k: np.ndarray) -> np.ndarray:
    """4x4 matrices T @ R @ S from K translations, unit quaternions (x, y, z, w) and scales."""
    q = q / np.where((n := np.linalg.norm(q, axis=1, keepdims=True)) > 0, n, 1.0)
    x, y, z, w = q.T
    r = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
                  2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                  2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1)
    m = np.tile(np.eye(4), (len(t), 1, 1))
    m[:, :3, :3] = r.reshape(-1, 3, 3) * k[:, None, :]
    m[:, :3, 3] = t
    return m

