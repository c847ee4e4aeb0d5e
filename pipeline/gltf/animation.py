"""glTF animations read into core.animation's plain data, through the document's accessors (so
sparse accessors, normalized integers and the file's limits apply as for geometry).

KHR_animation_pointer: a channel whose JSON pointer names a node's translation, rotation,
scale or weights becomes an ordinary channel on that node; one that names a number (or
numbers) of a material (its factors, alphaCutoff, normal scale, occlusion strength, any
material extension's factors, a texture slot's KHR_texture_transform offset / rotation /
scale), of a KHR_lights_punctual light (colour, intensity, range, cone angles) or of a
camera (perspective yfov / znear / zfar / aspectRatio, orthographic xmag / ymag / znear /
zfar) keeps its pointer: `write_pointers` sets the values at a time into the document, so
that the materials, lights and cameras read from it afterwards are the animated ones. Any
other pointer is left out with a warning.
"""
from __future__ import annotations

import re
from typing import cast

import numpy as np

from core.animation import Animation, Channel, Path
from pipeline.gltf.accessors import Document

PATHS = {"translation": 3, "rotation": 4, "scale": 3, "weights": None}
INTERPOLATIONS = ("LINEAR", "STEP", "CUBICSPLINE")


def read_animations(d: Document) -> list[Animation]:
    """Every animation of the document, channels checked: a bad
    sampler or accessor is a MalformedAsset naming the file and the channel; a channel on a
    path this reader does not animate (KHR_animation_pointer) is left out with a warning."""
    out = []
    for a, anim in enumerate(d.array(d.doc, "animations")):
        anim = d.obj(anim, f"animation {a}")
        samplers = d.array(anim, "samplers")
        channels = []
        for c, chan in enumerate(d.array(anim, "channels")):
            what = f"animation {a} channel {c}"
            chan = d.obj(chan, what)
            target = d.obj(chan.get("target"), f"{what} target")
            path = target.get("path")
            pointer = ""
            if path == "pointer":
                ext = d.obj(d.obj(target.get("extensions"), f"{what} target extensions")
                            .get("KHR_animation_pointer"), f"{what} KHR_animation_pointer")
                named = ext.get("pointer")
                if not isinstance(named, str):
                    raise d.bad(f"{what}: KHR_animation_pointer has no pointer string")
                pointer = named
                node_target = NODE_POINTER.match(pointer)
                if node_target:  # a node's TRS or weights: an ordinary channel
                    target = {"node": int(node_target.group(1))}
                    path, pointer = node_target.group(2), ""
                else:
                    problem = _pointer_problem(d, pointer)
                    if problem:
                        d.warnings.append(f"{what}: pointer {pointer!r} {problem} (kept at rest)")
                        continue
            if path not in PATHS and not pointer:
                d.warnings.append(f"{what}: path {path!r} is not animated (kept at rest)")
                continue
            if pointer:
                node = -1
            elif "node" not in target:
                continue  # the spec allows it: an extension's target, nothing here
            else:
                node = d.integer(target, "node")
                d.item("nodes", node, f"{what} target")
            s = d.integer(chan, "sampler")
            if s >= len(samplers):
                raise d.bad(f"{what}: sampler {s} is past the animation's {len(samplers)}")
            channels.append(_channel(d, d.obj(samplers[s], f"{what} sampler"),
                                     node, str(path), what, pointer))
        out.append(Animation(name=str(anim.get("name") or f"animation {a}"), channels=channels))
    return out


NODE_POINTER = re.compile(r"^/nodes/(\d+)/(translation|rotation|scale|weights)$")
# what a pointer may name: a material's numbers, a light's, a camera's
POINTERS = (
    re.compile(r"^/materials/(\d+)/[A-Za-z0-9_/]+$"),
    re.compile(r"^/extensions/KHR_lights_punctual/lights/(\d+)/"
               r"(color|intensity|range|spot/innerConeAngle|spot/outerConeAngle)$"),
    re.compile(r"^/cameras/(\d+)/(perspective/(yfov|znear|zfar|aspectRatio)|"
               r"orthographic/(xmag|ymag|znear|zfar))$"),
)
# objects a pointer may create on its way to a number: what glTF gives defaults for
CREATABLE = re.compile(r"^(extensions|pbrMetallicRoughness|spot|(KHR|EXT)_\w+)$")
# numbers a material reads that are not called *Factor (texture slots' and extensions' own)
MATERIAL_NUMBERS = re.compile(r"(Factor|alphaCutoff|/scale|/strength|/offset|/rotation|/ior|"
                              r"emissiveStrength|attenuationDistance|attenuationColor|"
                              r"iridescenceIor|iridescenceThickness\w+|anisotropyStrength|"
                              r"anisotropyRotation|dispersion)$")
WIDTHS = {"baseColorFactor": 4, "emissiveFactor": 3, "color": 3, "attenuationColor": 3,
          "sheenColorFactor": 3, "specularColorFactor": 3, "offset": 2}


def _pointer_problem(d: Document, pointer: str) -> str | None:
    """Why `pointer` cannot be animated here (None: it can): what it names must be a number
    (or numbers) of an object the document has, through objects glTF gives defaults for."""
    if not any(p.match(pointer) for p in POINTERS):
        return "is not one this reader animates"
    if pointer.startswith("/materials/") and not MATERIAL_NUMBERS.search(pointer):
        return "is not a material number this reader reads"
    keys = pointer.split("/")[1:]
    here: object = d.doc
    for i, key in enumerate(keys[:-1]):
        if isinstance(here, list):
            if not key.isdigit() or int(key) >= len(here):
                return "names an object the asset does not have"
            here = here[int(key)]
        elif isinstance(here, dict):
            if key not in here:
                # texture transforms on a slot that exists; never a texture slot itself
                if i >= 2 and all(CREATABLE.match(k) for k in keys[i:-1]):
                    return None
                return "names an object the asset does not have"
            here = here[key]
        else:
            return "runs through a value that is not an object"
    if isinstance(here, dict) and keys[-1] in here:
        value = here[keys[-1]]
        ok = isinstance(value, (int, float)) or (isinstance(value, list) and all(
            isinstance(v, (int, float)) for v in value))
        if not ok or isinstance(value, bool):
            return "names a value that is not a number"
    elif not isinstance(here, dict):
        return "names an object the asset does not have"
    return None


def pointer_width(d: Document, pointer: str) -> int:
    """How many numbers `pointer` holds: as authored, else as glTF defines the property."""
    keys = pointer.split("/")[1:]
    here: object = d.doc
    for key in keys:
        here = here[int(key)] if isinstance(here, list) else \
            (here.get(key) if isinstance(here, dict) else None)
        if here is None:
            break
    if isinstance(here, list):
        return len(here)
    if isinstance(here, (int, float)):
        return 1
    leaf = keys[-1]
    if leaf == "scale" and "KHR_texture_transform" in keys:
        return 2
    return WIDTHS.get(leaf, 1)


def write_pointers(d: Document, values: dict[str, np.ndarray]) -> None:
    """Set each pointer's value into the document (objects glTF defaults created on the
    way), so that what is read from it next reads the animated values."""
    for pointer, value in values.items():
        keys = pointer.split("/")[1:]
        here = d.doc
        for key in keys[:-1]:
            here = here[int(key)] if isinstance(here, list) else here.setdefault(key, {})
        v = [float(x) for x in np.ravel(value)]
        here[keys[-1]] = v[0] if len(v) == 1 and pointer_width(d, pointer) == 1 else v


def _channel(d: Document, sampler: dict, node: int, path: str, what: str,
             pointer: str = "") -> Channel:
    interpolation = sampler.get("interpolation", "LINEAR")
    if interpolation not in INTERPOLATIONS:
        raise d.bad(f"{what}: unknown interpolation {interpolation!r}")
    limit = d.limits.max_nodes * 1000  # keyframes: generous, but bounded
    times = d.accessor(d.integer(sampler, "input"), limit, f"{what} input")
    values = d.accessor(d.integer(sampler, "output"), limit * 3 * 256, f"{what} output")
    if times.shape[1] != 1:
        raise d.bad(f"{what}: input is not SCALAR")
    times = times[:, 0].astype(np.float64)
    if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise d.bad(f"{what}: input times are not finite and strictly increasing")
    per_key = 3 * len(times) if interpolation == "CUBICSPLINE" else len(times)
    width = pointer_width(d, pointer) if pointer else PATHS[path]
    values = values.astype(np.float64)
    if width is None:  # weights: one scalar per morph target, per key
        if values.shape[1] != 1 or len(values) % per_key:
            raise d.bad(f"{what}: {len(values)} weights do not divide into {per_key} keys")
        values = values.reshape(per_key, -1)
    elif values.shape != (per_key, width):
        raise d.bad(f"{what}: output is {values.shape[0]} x {values.shape[1]}, "
                          f"expected {per_key} x {width}")
    if not np.all(np.isfinite(values)):
        raise d.bad(f"{what}: output holds non-finite values")
    if interpolation == "CUBICSPLINE":
        values = values.reshape(len(times), 3, -1)
    if pointer:
        return Channel(node=-1, path="pointer", interpolation=interpolation, times=times,
                       values=values, node_name=pointer, pointer=pointer)
    return Channel(node=node, path=cast(Path, path), interpolation=interpolation, times=times,
                   values=values, node_name=d.name("nodes", node, "node"))
