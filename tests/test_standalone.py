"""The repository stands alone: no test, seed or shipped module reads `../shared` beside the
checkout, and every sample file a test names is in tests/assets with its licence noted."""
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ASSETS = Path(__file__).resolve().parent / "assets"
# ../shared written out, or built from path parts ("shared" / "assets", parent / "shared")
SHARED = re.compile(r"""["']\.\./shared|["']shared["']\s*/\s*["']assets|\.parent\s*/\s*["']shared["']""")
# assets / "gltf/Duck.glb", assets / "gltf" / "Duck.glb": literal paths only
NAMED = re.compile(r"""\bassets\s*/\s*((?:["'][\w./-]+["']\s*/?\s*)+)""")


def _sources():
    for wing in ("tests", "core", "gl", "pipeline", "renderer", "service", "cli"):
        yield from sorted((ROOT / wing).rglob("*.py"))


def test_no_source_reads_the_shared_folder():
    found = [f"{p.relative_to(ROOT)}:{n}" for p in _sources() if p.name != "test_standalone.py"
             for n, line in enumerate(p.read_text().splitlines(), 1) if SHARED.search(line)]
    assert not found, found


def test_every_named_sample_is_shipped():
    missing = []
    for p in sorted((ROOT / "tests").glob("*.py")):
        for m in NAMED.finditer(p.read_text()):
            parts = re.findall(r"""["']([\w./-]+)["']""", m.group(1))
            if not (ASSETS.joinpath(*parts)).exists():
                missing.append(f"{p.name}: {'/'.join(parts)}")
    assert not missing, missing


def test_every_asset_folder_has_its_licence_noted():
    sources = (ASSETS / "SOURCES.md").read_text()
    for folder in sorted(p for p in ASSETS.iterdir() if p.is_dir()):
        assert f"| {folder.name}/ |" in sources, folder.name
    for model in sorted((ASSETS / "gltf-samples").iterdir()):
        assert (model / "LICENSE.md").is_file() and model.name in sources, model.name
    assert (ASSETS / "usd" / "LICENSE-usd-wg-assets").is_file()


def test_the_wheel_ships_no_benchmarks_but_a_checkout_runs_them():
    include = re.search(r"\[tool.setuptools.packages.find\][^\[]*include = \[([^\]]*)\]",
                        (ROOT / "pyproject.toml").read_text(), re.S)
    assert include and "core*" in include.group(1) and "bench" not in include.group(1)
    p = subprocess.run([sys.executable, "-m", "cli.main", "bench", "--help"], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and "fidelity" in p.stdout, p.stderr[-2000:]
