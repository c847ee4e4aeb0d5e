"""bench thumbnail's report: a run without cold processes (`--cold-repeat 0`) prints its warm
figures and ratios, with no cold figure to divide."""
from __future__ import annotations

from bench import thumbnail


def test_report_without_cold_runs(capsys):
    warm = {"warm_ms": 12.0, "warm_png_ms": 15.0, "warm_cpu_ms": 20.0}
    row = {"asset": "Duck", "size": 512, "ours": {"cold_s": None, **warm},
           "pyrender": {"cold_s": None, **warm, "warm_ms": 24.0}}
    thumbnail._print_row(row, ["ours", "pyrender"])
    thumbnail._print_summary([row], ["ours", "pyrender"])
    out = capsys.readouterr().out
    assert "ours: cold -, warm 12.0 ms" in out
    assert "0.50" in out.splitlines()[-1] and out.splitlines()[-1].split()[-1] == "-"
