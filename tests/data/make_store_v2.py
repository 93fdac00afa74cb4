"""Make tests/data/store-v2.sqlite: a store written by the release before schema migrations (schema_version 2).

The store module of that release is taken from git history (commit 1a224dc, station/store.py) into a temporary
module, so that the fixture is what that software wrote:

    .venv/bin/python tests/data/make_store_v2.py
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from station.session import Measurement, PointRecord, RawStreams, StationInfo

PREVIOUS_RELEASE = "1a224dcb8680b44bf8d9463bdab48064e511a06c"
HERE = Path(__file__).resolve().parent
OUT = HERE / "store-v2.sqlite"


def previous_store_module():
    source = subprocess.run(["git", "-C", str(HERE), "show", f"{PREVIOUS_RELEASE}:station/store.py"],
                            capture_output=True, text=True, check=True).stdout  # fmt: skip
    path = Path(tempfile.mkdtemp()) / "store_v2.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("store_v2", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def make(out: Path = OUT) -> Path:
    """The fixture store, written by the previous release's store module."""
    old = previous_store_module()
    out.unlink(missing_ok=True)
    store = old.SessionStore(out)
    rng = np.random.default_rng(1)
    uid = store.create_session(StationInfo(latitude_deg=-33.92), "seed000.integral_precession",
                               instrument_serial="PIGA-0042", config={"procedure": "seed000.integral_precession",
                                                                      "params": {"positions_deg": [0.0]}})  # fmt: skip
    store.add_point(uid, PointRecord("P000-0deg-static", 0, 0.0, 0.0, 0.0, "static", 819200, 560.84))
    vib = PointRecord("P001-0deg-v10", 1, 600.0, 0.0, 10.0, "vibration", -819200, 560.7, 0.05, 0.03, 5607)
    store.add_point(uid, vib, RawStreams(rng.random(50), rng.random(50), np.sort(rng.random(80))))
    store.add_result(uid, "integral", {"kz": 0.56})
    store.set_status(uid, "finished")
    tumble = store.create_session(StationInfo(), "seed001.tumble", instrument_serial="Q-7")
    for i, (level, samples) in enumerate([(0.5, 10), (1.25, 12)]):  # an int and a float of one field, across rows
        values = {"J": i + 1, "volts": level, "samples": samples, "setup": None if i else "A"}
        store.add_measurement(tumble, Measurement(f"T1-J{i + 1}", "tumble", values, {"volts": rng.random(4)}))
    store.close()
    print(f"wrote {out} ({out.stat().st_size} bytes): sessions {uid}, {tumble}", file=sys.stderr)
    return out


if __name__ == "__main__":
    make()
