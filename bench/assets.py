"""Where the bench (and the tests that reuse its scenes) find the shared sample assets."""
from pathlib import Path

ASSETS = Path(__file__).resolve().parents[2] / "shared" / "assets"
