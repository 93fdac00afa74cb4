"""A procedure's analysis of a stored session, in a process of its own.

    python -m station.cli.analysis_job PROCEDURE STORE.sqlite UID REPORT.html
    python -m station.cli.analysis_job --serve    (then the four arguments as one JSON line on standard input)

The station's controller runs this after each session: fitting and plotting
can hold the interpreter for hundreds of milliseconds, and the drivers'
watchdogs in the controller's process (the drive's heartbeat is checked
every 25 ms) must not starve. With `--serve` the process imports the
procedure library first and then waits for its one job: the controller keeps
such a process ready (`start_analyst`) while a session runs, so the seconds of
imports are not added to the analysis (each analysis still gets a fresh
process). The session comes from the store (SQLite WAL: readable while the
station writes); the report goes to REPORT.html; the results and summary are
printed as one JSON document on standard output. Exit code 3 with the reason
on standard error when the data cannot give what the analysis asks (a
singular design, too few points).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from station.engine.registry import get_procedure, load_library
from station.htmlkit import with_provenance
from station.jsonsafe import json_safe
from station.store import SessionStore

CANNOT_ANALYSE = 3


def start_analyst() -> subprocess.Popen[str]:
    """A `--serve` process: it imports the library now and waits for its job on standard input."""
    return subprocess.Popen(
        [sys.executable, "-m", "station.cli.analysis_job", "--serve"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    args = argv if argv is not None else sys.argv[1:]
    if args == ["--serve"]:
        load_library()
        line = sys.stdin.readline()
        if not line:  # the controller closed without a job for it
            return 0
        args = json.loads(line)
    procedure, db_path, uid, report_path = args
    spec = get_procedure(procedure)
    if spec.analyse is None:
        print(f"procedure {procedure!r} has no analysis", file=sys.stderr)
        return CANNOT_ANALYSE
    with SessionStore(db_path) as store:
        session = store.load_session(uid, with_raw=False)
    try:
        analysis = spec.analyse(session)
    except ValueError as exc:  # FitError and kin
        print(str(exc), file=sys.stderr)
        return CANNOT_ANALYSE
    with open(report_path, "w") as f:
        f.write(with_provenance(analysis.report_html, session.provenance))  # every report says where it came from
    for name, content in analysis.files.items():  # beside the report, e.g. certificate-<uid>.pdf
        (Path(report_path).parent / Path(name).name).write_bytes(content)
    json.dump(json_safe({"results": analysis.results, "summary": analysis.summary}), sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
