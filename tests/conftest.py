from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# The curated sample assets shipped with the tests (tests/assets/SOURCES.md)
ASSETS = Path(__file__).resolve().parent / "assets"


def pytest_addoption(parser):
    parser.addoption("--update-goldens", action="store_true",
                     help="rewrite golden images in tests/goldens instead of comparing")


@pytest.fixture(scope="session")
def assets() -> Path:
    if not ASSETS.is_dir():
        pytest.fail(f"test assets not found at {ASSETS}")
    return ASSETS


@pytest.fixture(scope="session")
def update_goldens(request) -> bool:
    return request.config.getoption("--update-goldens")


@pytest.fixture(scope="session")
def reference_env(tmp_path_factory):
    """The environment the Mitsuba references were rendered with, baked at 512 px faces: the
    cube resampling of a 256 px bake alone costs ~0.05 relative error against them."""
    from pipeline.bake import bake_environment
    return bake_environment("footprint_court", tmp_path_factory.mktemp("reference_env"),
                                     face_size=512)


@pytest.fixture(scope="session")
def scene_cache(tmp_path_factory):
    """One bake cache for the generated glass test scenes (bench/scenes.py)."""
    return tmp_path_factory.mktemp("scene_cache")


@pytest.fixture(scope="session")
def server(tmp_path_factory):
    """One real `asset-preview serve` process (two workers, the limits in service_server.py)
    for every test whose server settings are these: starting one costs seconds."""
    from service_server import ARGS, SERVER_ENV, Server
    srv = Server(tmp_path_factory.mktemp("svc") / "cache", *ARGS, env=SERVER_ENV)
    try:
        srv.wait_ready()
        yield srv
    finally:
        srv.stop()
