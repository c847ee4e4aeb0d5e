"""A render worker's warm-up leaves nothing for its first request to compile."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_PROBE = """
import sys
from renderer.methods import trace_kernel
from service.workers.jobs import WorkerConfig, WorkerState
before = len(trace_kernel.shade.signatures)
info = WorkerState(WorkerConfig(cache_dir=sys.argv[1])).ping()
print(before, len(trace_kernel.shade.signatures), info.warm_seconds)
"""


def test_warm_up_loads_the_ray_tracer_kernel(tmp_path):
    # A fresh process: in this one another test may have compiled the kernel already.
    out = subprocess.run([sys.executable, "-c", _PROBE, str(tmp_path)], cwd=ROOT, check=True,
                         capture_output=True, text=True, env={**os.environ, "PYOPENGL_PLATFORM": "egl"})
    before, after, _ = out.stdout.split()
    assert int(before) == 0 and int(after) > 0
