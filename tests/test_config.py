"""core.config.FromEnv: arguments over ASSET_PREVIEW_* variables over defaults."""
from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from core.config import RendererSettings
from pipeline.limits import Limits, PipelineSettings


def test_variables_parse_as_their_fields_and_arguments_win(monkeypatch):
    monkeypatch.setenv("ASSET_PREVIEW_MAX_VERTICES", "1234")
    monkeypatch.setenv("asset_preview_ingest_seconds", "2.5")  # names match case-insensitively
    monkeypatch.setenv("ASSET_PREVIEW_CACHE", "/tmp/somewhere")
    monkeypatch.setenv("ASSET_PREVIEW_NOT_A_KNOB", "x")  # another class's knob, or none: ignored
    limits = Limits.from_env(max_textures=None)
    assert (limits.max_vertices, limits.ingest_seconds, limits.max_textures) == (1234, 2.5, 512)
    assert Limits.from_env(max_vertices=7).max_vertices == 7
    assert PipelineSettings().cache == Path("/tmp/somewhere")
    assert RendererSettings().gpu_bytes == 512 * 2**20


def test_a_malformed_variable_is_refused_naming_the_knob(monkeypatch):
    monkeypatch.setenv("ASSET_PREVIEW_GPU_ENVIRONMENTS", "many")
    with pytest.raises(ValidationError, match="gpu_environments"):
        RendererSettings()
    monkeypatch.setenv("ASSET_PREVIEW_GPU_ENVIRONMENTS", "0")  # below its bound (ge=1)
    with pytest.raises(ValidationError, match="gpu_environments"):
        RendererSettings()
