"""pipeline.bake.installed_versions (the bake record's versions) reads what
importlib.metadata.version reads, without importing it."""
import subprocess
import sys
from importlib import metadata
from pathlib import Path

from pipeline.bake import installed_versions

ROOT = Path(__file__).resolve().parents[1]


def test_every_installed_distribution_reads_as_importlib_metadata_reads_it():
    names = sorted({d.metadata["Name"] for d in metadata.distributions()} | {"no-such-dist"})
    expected = {}
    for n in names:
        try:
            expected[n] = metadata.version(n)
        except metadata.PackageNotFoundError:
            pass
    assert installed_versions(names) == expected
    assert "numpy" in expected  # the lookup found something


def test_reading_versions_imports_no_importlib_metadata():
    code = ("import sys; from pipeline.bake import installed_versions; "
            "v = installed_versions(['numpy', 'moderngl', 'usd-core']); "
            "print(len(v), 'importlib.metadata' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["3", "False"]
