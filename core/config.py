"""Configuration machinery: flags, then ASSET_PREVIEW_* variables, then defaults
(pydantic-settings; one declaration per knob). The knobs live with what they configure:
pipeline/limits.py (input limits, pipeline), service/settings.py (the service), and the
renderer's GPU budget here (the renderer may import core only)."""
from __future__ import annotations

from functools import lru_cache

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

ENV_PREFIX = "ASSET_PREVIEW_"


class FromEnv(BaseSettings):
    model_config = SettingsConfigDict(env_prefix=ENV_PREFIX, frozen=True, extra="ignore")

    @classmethod
    def from_env(cls, **overrides):
        """Defaults, overridden by ASSET_PREVIEW_<FIELD> variables, overridden by arguments
        (arguments that are None are ignored, so argparse results can be passed as they are)."""
        return cls(**{k: v for k, v in overrides.items() if v is not None})


class RendererSettings(FromEnv):
    """How much a renderer process keeps uploaded (the service sets its workers' own)."""
    gpu_bytes: int = Field(512 * 2**20, ge=1, description="bytes of meshes and textures a renderer keeps uploaded")
    gpu_environments: int = Field(4, ge=1, description="environments kept uploaded")


@lru_cache(maxsize=1)
def renderer_settings() -> RendererSettings:
    """The environment's renderer settings, read once."""
    return RendererSettings()
