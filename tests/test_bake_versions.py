"""The versions a bake records come from dist-info folder names: the same answer as
importlib.metadata, which the cold path no longer asks."""
from importlib import metadata

from pipeline.bake import _RECORDED, _versions, installed_versions


def _by_metadata(names):
    out = {}
    for name in names:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return out


def test_installed_versions_match_importlib_metadata():
    # Spellings as people write them (case, dots, underscores) and a name nothing provides.
    names = (*_RECORDED, "pydantic", "Pillow", "zstandard", "PyYAML", "typing_extensions",
             "no-such-distribution-here")
    got = installed_versions(names)
    assert got == _by_metadata(names)
    assert "no-such-distribution-here" not in got
    assert got["numpy"] and got["usd-core"]


def test_recorded_versions_in_the_manifest_order():
    v = _versions()
    assert list(v)[:2] == ["bake_format", "python"]
    assert {k: v[k] for k in _RECORDED if k in v} == _by_metadata(_RECORDED)
