"""Animations as plain data, and their evaluation at a time.

A `Channel` is a glTF animation channel with its sampler folded in: the node it drives, the
property (`translation`, `rotation`, `scale` or morph `weights`), the interpolation and the
keyframes. `Animation.pose(t)` evaluates every channel at `t` seconds into per-node values
that a reader composes in place of the node's own (pipeline.gltf.reader); a
KHR_animation_pointer channel on anything else (a material factor, a texture transform, a
light's colour, a camera's yfov) keeps its JSON pointer, and `Animation.pointers(t)` gives
their values, which the reader writes into the document before it reads those objects. Interpolation is
as the glTF 2.0 specification defines it (Appendix C): STEP holds the previous key, LINEAR
lerps (rotations by shortest-arc slerp), CUBICSPLINE is the Hermite spline over the
in-tangent / value / out-tangent triplets, tangents scaled by the key interval; before the
first key and after the last the end values hold. A `Moment` names what a request asks for.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from core.errors import NotInAsset

Path = Literal["translation", "rotation", "scale", "weights", "pointer"]
Interpolation = Literal["LINEAR", "STEP", "CUBICSPLINE"]
POSTER = "poster"


@dataclass(frozen=True)
class Moment:
    """The time a request asks to see: `time` in seconds (glTF seconds; USD time codes
    through timeCodesPerSecond, from the stage's start) or `poster` (core.animation.poster_time),
    of the animation named or indexed by `animation` (None: the first)."""
    time: float | str
    animation: str | None = None


@dataclass
class Channel:
    node: int
    path: Path
    interpolation: Interpolation
    times: np.ndarray   # K, float64, strictly increasing
    values: np.ndarray  # K x W (K x 3 x W for CUBICSPLINE: in-tangent, value, out-tangent)
    node_name: str = ""  # for people: what inspect lists
    pointer: str = ""  # path "pointer": the JSON pointer it drives (KHR_animation_pointer; node -1)

    def sample(self, t: float) -> np.ndarray:
        """The channel's value at `t` seconds (W,), float64."""
        return sample(self.times, self.values, self.interpolation, t,
                      quaternion=self.path == "rotation")


@dataclass
class Animation:
    name: str
    channels: list[Channel] = field(default_factory=list)

    @property
    def start(self) -> float:
        return min((float(c.times[0]) for c in self.channels), default=0.0)

    @property
    def end(self) -> float:
        return max((float(c.times[-1]) for c in self.channels), default=0.0)

    @property
    def duration(self) -> float:
        return self.end - self.start

    def pose(self, t: float) -> dict[int, dict[str, np.ndarray]]:
        """node -> {path: value at t} for every node a channel drives."""
        out: dict[int, dict[str, np.ndarray]] = {}
        for c in self.channels:
            if not c.pointer:
                out.setdefault(c.node, {})[c.path] = c.sample(t)
        return out

    def pointers(self, t: float) -> dict[str, np.ndarray]:
        """JSON pointer -> value at t, for every KHR_animation_pointer channel that does
        not drive a node's TRS or weights (those are ordinary channels)."""
        return {c.pointer: c.sample(t) for c in self.channels if c.pointer}

    def summary(self) -> dict:
        """What `inspect` lists: name, time range, channels and what they drive."""
        return {"name": self.name, "start": round(self.start, 6), "duration": round(self.duration, 6),
                "channels": len(self.channels),
                "targets": [{"node": c.node, "name": c.node_name, "path": c.path,
                             "interpolation": c.interpolation, "keys": len(c.times),
                             **({"pointer": c.pointer} if c.pointer else {})}
                            for c in sorted(self.channels, key=lambda c: (c.node, c.path, c.pointer))]}


def poster_time(animation: Animation) -> float:
    """The poster frame: the middle of the animation's time range. Chosen over "widest
    silhouette" because it needs no render to find, is deterministic, and for the loops
    libraries mostly hold (walks, runs, idles, spins) lands mid-motion, away from the start
    pose that exporters often leave at or near the bind pose."""
    return animation.start + 0.5 * animation.duration


def sample(times: np.ndarray, values: np.ndarray, interpolation: str, t: float,
           quaternion: bool = False) -> np.ndarray:
    """Keyframes (`times` K, `values` K x W or K x 3 x W for CUBICSPLINE) at time `t`."""
    cubic = interpolation == "CUBICSPLINE"
    v = values[:, 1] if cubic else values
    k = len(times)
    if k == 1 or t <= times[0]:
        return _finish(v[0].astype(np.float64), quaternion)
    if t >= times[-1]:
        return _finish(v[-1].astype(np.float64), quaternion)
    i = int(np.searchsorted(times, t, side="right")) - 1  # times[i] <= t < times[i + 1]
    t0, t1 = float(times[i]), float(times[i + 1])
    dt = t1 - t0
    u = (t - t0) / dt
    a, b = v[i].astype(np.float64), v[i + 1].astype(np.float64)
    if interpolation == "STEP":
        return _finish(a, quaternion)
    if cubic:
        out_tangent = values[i, 2].astype(np.float64) * dt
        in_tangent = values[i + 1, 0].astype(np.float64) * dt
        u2, u3 = u * u, u * u * u
        p = ((2 * u3 - 3 * u2 + 1) * a + (u3 - 2 * u2 + u) * out_tangent
             + (-2 * u3 + 3 * u2) * b + (u3 - u2) * in_tangent)
        return _finish(p, quaternion)
    if quaternion:
        return slerp(a, b, u)
    return a + (b - a) * u


def slerp(a: np.ndarray, b: np.ndarray, u: float) -> np.ndarray:
    """Spherical interpolation of unit quaternions (x, y, z, w) along the shorter arc."""
    a, b = _unit(a), _unit(b)
    d = float(np.dot(a, b))
    if d < 0.0:  # q and -q are one rotation: take the short way round
        b, d = -b, -d
    if d > 0.9995:  # nearly parallel: lerp is exact to float precision and avoids 0 / 0
        return _unit(a + (b - a) * u)
    theta = np.arccos(d)
    return (np.sin((1 - u) * theta) * a + np.sin(u * theta) * b) / np.sin(theta)


def _unit(q: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(q))
    return q / n if n > 0 else np.array([0.0, 0.0, 0.0, 1.0])


def _finish(v: np.ndarray, quaternion: bool) -> np.ndarray:
    # a cubic spline leaves unit length; glTF says to normalise the result
    return _unit(v) if quaternion else v


def select(animations: list, spec: str | None, source: str = "asset"):
    """The animation `spec` names (a name, or an index N), the first when None; `animations`
    holds Animations or their summary() dicts."""
    if not animations:
        raise NotInAsset(source, "has no animations (--time and --animate need one)")
    if spec is None:
        return animations[0]
    names = [a["name"] if isinstance(a, dict) else a.name for a in animations]
    if spec in names:
        return animations[names.index(spec)]
    if spec.isdigit() and int(spec) < len(animations):
        return animations[int(spec)]
    raise NotInAsset(source, f"no animation {spec!r}; it has "
                             f"{', '.join(f'{i} {n!r}' for i, n in enumerate(names))}")


def seconds(moment: Moment, animation: Animation) -> float:
    """The moment's time in seconds of `animation` (poster resolved)."""
    return poster_time(animation) if moment.time == POSTER else float(moment.time)


def requested(options) -> Moment | None:
    """The Moment a core.options.RenderOptions asks for: its `time` (seconds or poster) of
    its `animation`; an animation named without a time shows its poster frame; neither: None
    (the asset at rest)."""
    if options.time is None and options.animation is None:
        return None
    t = POSTER if options.time in (None, POSTER) else float(options.time)
    return Moment(time=t, animation=options.animation)
