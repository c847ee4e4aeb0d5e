"""The manual's tables are the schema's, not hand-kept copies: the render options
(core/options.py) in docs/cli.md, the service settings in docs/http.md. When this fails,
paste the table from the failure message between the markers."""
import re
import typing
from pathlib import Path

from core.options import request_fields

DOCS = Path(__file__).resolve().parents[1] / "docs"
CLI, HTTP = DOCS / "cli.md", DOCS / "http.md"
MARK = re.compile(r"<!-- render-options -->\n(.*?)<!-- /render-options -->", re.S)


def _type(ann) -> str:
    if typing.get_origin(ann) is not typing.Literal:
        ann = next((a for a in typing.get_args(ann) if a is not type(None)), ann)
    if typing.get_origin(ann) is typing.Literal:
        return " \\| ".join(f"`{v}`" for v in typing.get_args(ann))
    return getattr(ann, "__name__", str(ann))


def _range(info) -> str:
    b = info.bounds
    lo, hi = b.ge if b.ge is not None else b.gt, b.le
    return f"{lo:g}..{hi:g}" if lo is not None and hi is not None else ""


def table() -> str:
    rows = ["| parameter (`--flag`) | type | range | default | what it does |", "|---|---|---|---|---|"]
    for name, info in request_fields().items():
        default = info.default
        shown = "" if default is None else f"`{default}`"
        flag = "--" + name.replace("_", "-")
        if isinstance(default, bool):
            flag += f"`, `--no-{name.replace('_', '-')}"
        text = (info.description or "").replace("|", "\\|")
        rows.append(f"| `{name}` (`{flag}`) | {_type(info.annotation)} | {_range(info)} | {shown} | {text} |")
    return "\n".join(rows) + "\n"


def test_cli_reference_lists_the_render_options_from_the_schema():
    m = MARK.search(CLI.read_text())
    assert m, "docs/cli.md has no <!-- render-options --> block"
    assert m.group(1) == table(), "docs/cli.md's render options differ from the schema; use:\n" + table()


def test_http_reference_lists_every_setting_from_its_declaration():
    """The settings tables are `python -m cli.serve`'s output: every row as declared now."""
    from cli.serve import settings_table
    from core.config import RendererSettings
    from pipeline.limits import Limits, PipelineSettings
    text = HTTP.read_text()
    for model, flags in ((None, True), (Limits, False), (PipelineSettings, False), (RendererSettings, False)):
        rows = (settings_table() if model is None else settings_table(model, flags)).splitlines()[2:]
        missing = [r for r in rows if r not in text]
        assert not missing, "docs/http.md's settings differ from the declarations; run python -m cli.serve:\n" + "\n".join(missing)
