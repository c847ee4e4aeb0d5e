"""Cost of a MaterialX image's re-encoded copy: the median of 7 `_Recoded` copies of one
1024 x 1024 RGBA texture (random bytes) for an sRGB slot, from lin_rec709 (channel-wise) and,
where the checkout converts gamuts, from acescg (a 3x3 matrix per texel). Runs against any
checkout: `cp bench/mtlx_recode.py /tmp/mr.py; cd CHECKOUT && PYTHONPATH=CHECKOUT python
/tmp/mr.py`."""
import inspect
import statistics
import time

import numpy as np

from core.scene import Texture
from pipeline.usd import materials

RECODED = getattr(materials, "_Recoded")  # noqa: B009  # the class under test, private to materials


def _median_ms(base: Texture, *space) -> float:
    times = []
    for _ in range(7):
        t = time.perf_counter()
        _ = RECODED("r", base, True, *space).image
        times.append(time.perf_counter() - t)
    return statistics.median(times) * 1e3


def main() -> None:
    rng = np.random.default_rng(0)
    base = Texture(name="t", image=rng.integers(0, 256, (1024, 1024, 4), dtype=np.uint8))
    line = f"lin_rec709 -> sRGB slot {_median_ms(base):.1f} ms"
    if "space" in inspect.signature(RECODED).parameters:
        line += f", acescg -> sRGB slot {_median_ms(base, ('linear', 'ap1')):.1f} ms"
    print(line)


if __name__ == "__main__":
    main()
