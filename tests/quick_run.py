"""A quick seed-000 session run by `station run` on the simulated station (20 points, 30 s windows, about
20 s of wall time), shared by the console and notebook tests (tests/ is on pytest's path)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
QUICK_TOML = ('procedure = "integral_precession"\ntitle = "quick"\n[params]\n'
              "positions_deg = [0, 72, 144, 216, 288]\nfreqs_hz = [8, 9, 10]\nwindow_s = 30\n")  # fmt: skip
RUN_TIMEOUT_S = 240.0  # a loaded 2-core machine


def run_quick_session(out: Path) -> subprocess.CompletedProcess:
    """`station run` of the quick session with OUT as --out; its stdout and stderr apart. Fails on an error."""
    (out / "quick.toml").write_text(QUICK_TOML)
    r = subprocess.run([sys.executable, "-m", "station.cli.cli", "run", str(out / "quick.toml"), "--out", str(out)],
                       capture_output=True, text=True, cwd=REPO, timeout=RUN_TIMEOUT_S)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    return r
