"""Error of a linear frame against a committed Mitsuba reference, and the Pareto front.

Both images are linear radiance (H x W x 4; the reference's alpha is object coverage).

- FLIP: NVIDIA's HDR-FLIP (flip-evaluator, "HDR" mode) fed the linear RGB as it is: HDR-FLIP
  tone maps both images itself over the range of exposures the reference spans (its default
  start/stop exposures, ACES tone mapper) and keeps the worst per pixel. We report the mean of
  its error map over the object's pixels and over the whole frame.
- relative MSE: mean over pixels and channels of (x - y)^2 / (y^2 + REL_MSE_EPS), the usual
  rendering definition (Rousselle et al.), which weighs dark and bright pixels alike.

The object's pixels are those the reference's coverage marks (alpha > 0).
"""
from __future__ import annotations

import statistics
import time

import numpy as np

REL_MSE_EPS = 1e-2


def reference_at(name: str, size: int) -> np.ndarray:
    """The committed reference for scene `name` at `size` px: a larger one whose size is a
    multiple is box-filtered down (exact: Mitsuba's pixel filter is a box)."""
    from bench.reference import load_reference

    ref = load_reference(name)
    h = ref.shape[0]
    if h == size:
        return ref
    if h < size or h % size:
        raise FileNotFoundError(f"reference {name!r} is {h} px; cannot make {size} px from it "
                                f"(python -m bench.reference --scenes {name} --size {size})")
    k = h // size
    return ref.reshape(size, k, size, k, 4).mean(axis=(1, 3), dtype=np.float64).astype(np.float32)


def flip_map(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """HDR-FLIP error map (H x W, 0..1) of linear RGB against the reference."""
    import flip_evaluator

    ref = np.ascontiguousarray(np.clip(reference[..., :3], 0, None), np.float32)
    img = np.ascontiguousarray(np.clip(np.nan_to_num(image[..., :3], nan=0.0, posinf=0.0), 0, None),
                               np.float32)
    emap, _, _ = flip_evaluator.evaluate(ref, img, "HDR", inputsRGB=False, applyMagma=False,
                                         computeMeanError=False)
    return np.asarray(emap, np.float64).reshape(ref.shape[:2])


def rel_mse_map(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    x = np.nan_to_num(image[..., :3].astype(np.float64), nan=0.0, posinf=0.0)
    y = reference[..., :3].astype(np.float64)
    return ((x - y) ** 2 / (y * y + REL_MSE_EPS)).mean(axis=-1)


def errors(image: np.ndarray, reference: np.ndarray) -> dict:
    """flip / rel_mse over the object's pixels, flip_frame / rel_mse_frame over the frame."""
    mask = reference[..., 3] > 0
    if not mask.any():
        mask = np.ones(mask.shape, bool)
    f, r = flip_map(image, reference), rel_mse_map(image, reference)
    return {"flip": float(f[mask].mean()), "rel_mse": float(r[mask].mean()),
            "flip_frame": float(f.mean()), "rel_mse_frame": float(r.mean())}


def dominated(point: tuple[float, float], points) -> bool:
    """Whether some (time, error) point is at least as good as `point` on both axes and better
    on one (so never `point` itself)."""
    t, e = point
    return any(t2 <= t and e2 <= e and (t2 < t or e2 < e) for t2, e2 in points)


def pareto_front(points: list[tuple[float, float]]) -> list[bool]:
    """Whether each (time, error) point is on the front: no other point dominates it."""
    return [not dominated(p, points) for p in points]


def front_gap(point: tuple[float, float], front: list[tuple[float, float]]) -> float:
    """How far `point` is from the front, relatively, on its worse axis: the smallest over
    front points p of max(t / t_p, e / e_p) - 1 (<= 0: on or below the front; 0.1: within 10%
    of some front point on both axes)."""
    t, e = point
    return min((max(t / max(tp, 1e-12), e / max(ep, 1e-12)) - 1.0 for tp, ep in front),
               default=0.0)


def with_linear(frame):
    """`frame` with its linear image read: renderer.raster.render draws it only when asked for, so a
    timed render whose linear image is the measured product reads it inside the timing."""
    _ = frame.linear
    return frame


def median_ms(fn, repeat: int, warm: bool = True):
    """(median wall ms over `repeat` calls, last result); `warm` runs `fn` once untimed first
    (thread pools, shader compiles, uploads)."""
    if warm:
        fn()
    times, result = [], None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        result = fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times), result
