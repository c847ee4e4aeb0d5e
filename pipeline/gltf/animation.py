"""glTF animations read into core.animation's plain data, through the document's accessors (so
sparse accessors, normalized integers and the file's limits apply as for geometry)."""
from __future__ import annotations

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
            if path not in PATHS:
                d.warnings.append(f"{what}: path {path!r} is not animated (kept at rest)")
                continue
            if "node" not in target:
                continue  # the spec allows it: an extension's target, nothing here
            node = d.integer(target, "node")
            d.item("nodes", node, f"{what} target")
            s = d.integer(chan, "sampler")
            if s >= len(samplers):
                raise d.bad(f"{what}: sampler {s} is past the animation's {len(samplers)}")
            channels.append(_channel(d, d.obj(samplers[s], f"{what} sampler"),
                                     node, path, what))
        out.append(Animation(name=str(anim.get("name") or f"animation {a}"), channels=channels))
    return out


def _channel(d: Document, sampler: dict, node: int, path: str, what: str) -> Channel:
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
    width = PATHS[path]
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
    return Channel(node=node, path=cast(Path, path), interpolation=interpolation, times=times,
                   values=values, node_name=d.name("nodes", node, "node"))
