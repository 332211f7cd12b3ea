"""The figures the README and the quick example quote from simulations still hold on this engine:
``docs/figures.py --check`` simulates them again (9 quick runs on the local pool) and names each
stale line."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_the_documented_simulation_figures_are_what_the_engine_gives(tmp_path):
    proc = subprocess.run(
        [sys.executable, str(ROOT / "docs" / "figures.py"), "--check"],
        capture_output=True, text=True, timeout=900, cwd=tmp_path,
    )  # fmt: skip

    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "every figure holds" in proc.stdout
