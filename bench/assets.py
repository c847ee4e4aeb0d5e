"""Where the bench (and the tests that reuse its scenes) find sample assets.

`ASSETS` is the curated set the repository ships (tests/assets), so a clone needs nothing beside
it; `CORPUS` is the larger sample folder `../shared/assets` beside the checkout when it is there
(the corpus benchmarks default to it), else the same curated set."""
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ASSETS = REPO / "tests" / "assets"
SHARED = REPO.parent / "shared" / "assets"
CORPUS = SHARED if SHARED.is_dir() else ASSETS
