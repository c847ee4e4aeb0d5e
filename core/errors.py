"""Errors raised for rejected input. Every message names the file and the reason."""
from __future__ import annotations

import os


class AssetError(Exception):
    """An input asset was rejected. `str(err)` is `FILE: REASON`."""

    def __init__(self, path: str | os.PathLike, reason: str):
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")

    def __reduce__(self):
        # Crosses process boundaries (render workers, Ray) as its own class with both fields.
        return (type(self), (self.path, self.reason))


class UnsupportedFormat(AssetError):
    """The file type is not one we ingest."""


class MalformedAsset(AssetError):
    """The file is corrupt, truncated or violates its format's specification."""


class MissingFile(AssetError):
    """A file the asset references does not exist."""


class UnsafeReference(AssetError):
    """A reference points outside the asset's folder, at the network, or through a link out."""


class LimitExceeded(AssetError):
    """A count or size is beyond the configured limits (checked before allocating)."""


class EmptyScene(AssetError):
    """The asset holds nothing that renders."""


class IngestTimeout(AssetError):
    """Parsing took longer than the configured time bound."""


class NotInAsset(AssetError):
    """A request names a part the asset does not have (a material variant, a camera)."""
