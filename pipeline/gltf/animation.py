"""glTF animations read into core.animation's plain data, through the reader's accessors (so
sparse accessors, normalized integers and the file's limits apply as for geometry)."""
from __future__ import annotations

from typing import cast

import numpy as np

from core.animation import Animation, Channel, Path

PATHS = {"translation": 3, "rotation": 4, "scale": 3, "weights": None}
INTERPOLATIONS = ("LINEAR", "STEP", "CUBICSPLINE")


def read_animations(reader) -> list[Animation]:
    """Every animation of the file (pipeline.gltf.reader._Reader), channels checked: a bad
    sampler or accessor is a MalformedAsset naming the file and the channel; a channel on a
    path this reader does not animate (KHR_animation_pointer) is left out with a warning."""
    out = []
    for a, anim in enumerate(reader._list(reader.doc, "animations")):
        anim = reader._dict(anim, f"animation {a}")
        samplers = reader._list(anim, "samplers")
        channels = []
        for c, chan in enumerate(reader._list(anim, "channels")):
            what = f"animation {a} channel {c}"
            chan = reader._dict(chan, what)
            target = reader._dict(chan.get("target"), f"{what} target")
            path = target.get("path")
            if path not in PATHS:
                reader.warnings.append(f"{what}: path {path!r} is not animated (kept at rest)")
                continue
            if "node" not in target:
                continue  # the spec allows it: an extension's target, nothing here
            node = reader._int(target, "node")
            reader._get("nodes", node, f"{what} target")
            s = reader._int(chan, "sampler")
            if s >= len(samplers):
                raise reader._bad(f"{what}: sampler {s} is past the animation's {len(samplers)}")
            channels.append(_channel(reader, reader._dict(samplers[s], f"{what} sampler"),
                                     node, path, what))
        out.append(Animation(name=str(anim.get("name") or f"animation {a}"), channels=channels))
    return out


def _channel(reader, sampler: dict, node: int, path: str, what: str) -> Channel:
    interpolation = sampler.get("interpolation", "LINEAR")
    if interpolation not in INTERPOLATIONS:
        raise reader._bad(f"{what}: unknown interpolation {interpolation!r}")
    limit = reader.limits.max_nodes * 1000  # keyframes: generous, but bounded
    times = reader.accessor(reader._int(sampler, "input"), limit, f"{what} input")
    values = reader.accessor(reader._int(sampler, "output"), limit * 3 * 256, f"{what} output")
    if times.shape[1] != 1:
        raise reader._bad(f"{what}: input is not SCALAR")
    times = times[:, 0].astype(np.float64)
    if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise reader._bad(f"{what}: input times are not finite and strictly increasing")
    per_key = 3 * len(times) if interpolation == "CUBICSPLINE" else len(times)
    width = PATHS[path]
    values = values.astype(np.float64)
    if width is None:  # weights: one scalar per morph target, per key
        if values.shape[1] != 1 or len(values) % per_key:
            raise reader._bad(f"{what}: {len(values)} weights do not divide into {per_key} keys")
        values = values.reshape(per_key, -1)
    elif values.shape != (per_key, width):
        raise reader._bad(f"{what}: output is {values.shape[0]} x {values.shape[1]}, "
                          f"expected {per_key} x {width}")
    if not np.all(np.isfinite(values)):
        raise reader._bad(f"{what}: output holds non-finite values")
    if interpolation == "CUBICSPLINE":
        values = values.reshape(len(times), 3, -1)
    return Channel(node=node, path=cast(Path, path), interpolation=interpolation, times=times,
                   values=values, node_name=reader._name("nodes", node))
