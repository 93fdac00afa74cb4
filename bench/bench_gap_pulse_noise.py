"""The pulse test's noise model on records whose truth is known (issue 28, d3): Monte Carlo of pulse records.

Records of tests/gap/test_false_alarms.py (a rate 0.5 (1 - 0.9 sin psi + 0.05 cos 2 psi) rad/s at 5 Hz over 2 s,
~2600 edges stamped in 50 ns ticks with Gaussian jitter, the angle carrying a random walk of density D: white
rate noise), each reduced by station.gap.rawstreams._pulse_lsq. Per D: the mean over the records of each harmonic's
squared deviation over the variance the pulse test assumes (1 when the model is right; sd sqrt(2 / (6 reps))),
the same without the walk's term, and the median density the records imply.

    .venv/bin/python bench/bench_gap_pulse_noise.py [--reps 150]

Simulation path: neither the engine nor session_sim: synthetic pulse records made in the test.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--reps", type=int, default=150)
    p.add_argument("--jitter", type=float, default=1e-7, help="stamp jitter, s")
    args = p.parse_args(argv)
    spec = importlib.util.spec_from_file_location("test_false_alarms", ROOT / "tests" / "gap" / "test_false_alarms.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    pulse_chi2_per_dof = module.pulse_chi2_per_dof

    for k, diffusion in enumerate((0.0, 1e-10, 1e-9)):
        with_walk, without_walk, density = pulse_chi2_per_dof(diffusion, args.jitter, 100 + k, args.reps)
        row = {"D_rad2_per_s": diffusion, "jitter_s": args.jitter, "records": args.reps}
        row |= {"chi2_per_dof": round(with_walk, 3), "chi2_per_dof_without_walk": round(without_walk, 3)}
        print(json.dumps(row | {"median_density_found": density}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
