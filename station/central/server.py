"""A throwaway PostgreSQL cluster on a unix socket in a temporary directory (tests, benchmarks, a first try).

Debian's `postgresql` package provides initdb and pg_ctl under /usr/lib/postgresql/<major>/bin; the server
refuses to run as root, so as root the cluster belongs to the `postgres` account the package creates. Nothing
listens on TCP (listen_addresses is empty): only this machine's processes reach the socket.
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import subprocess
import tempfile
from pathlib import Path

from station.errors import StationFault

INSTALL_HINT = "apt-get update && apt-get install -y postgresql"
SERVER_USER = "postgres"  # the account Debian's package creates; the server refuses to run as root


class ServerError(StationFault):
    """PostgreSQL is not installed, or the throwaway cluster would not start."""


def pg_bin_dir(root: str | Path = "/usr/lib/postgresql") -> Path:
    """The newest <root>/<major>/bin that has initdb, or ServerError saying how to install one."""
    found = sorted(glob.glob(f"{root}/*/bin/initdb"), key=lambda p: int(Path(p).parts[-3]))
    if not found:
        raise ServerError(f"PostgreSQL is not installed (no {root}/*/bin/initdb): run `{INSTALL_HINT}`")
    return Path(found[-1]).parent


class ThrowawayServer:
    """initdb + pg_ctl start in a fresh directory; `url` for SQLAlchemy; stop() removes everything."""

    def __init__(self, database: str = "central", port: int = 5432) -> None:
        self.bin = pg_bin_dir()
        self.database = database
        self.port = port
        self.dir = Path(tempfile.mkdtemp(prefix="pgtmp-"))  # short: a unix socket path has ~100 characters
        self._user = SERVER_USER if os.geteuid() == 0 else None
        if self._user is not None:
            try:
                entry = pwd.getpwnam(self._user)
            except KeyError:
                raise ServerError(f"no {self._user!r} account to run the server as: run `{INSTALL_HINT}`") from None
            os.chown(self.dir, entry.pw_uid, entry.pw_gid)
        self.role = self._user or pwd.getpwuid(os.geteuid()).pw_name
        self._started = False

    def _run(self, *args: str) -> None:
        done = subprocess.run([str(self.bin / args[0]), *args[1:]], user=self._user, capture_output=True, text=True)
        if done.returncode != 0:
            raise ServerError(f"{args[0]} failed (exit {done.returncode}): {done.stderr.strip() or done.stdout}")

    def start(self) -> ThrowawayServer:
        data = self.dir / "data"
        self._run("initdb", "-D", str(data), "-A", "trust", "-U", self.role, "-E", "UTF8", "--no-sync")
        opts = f"-k {self.dir} -c listen_addresses= -p {self.port} -c fsync=off -c full_page_writes=off"
        self._run("pg_ctl", "-D", str(data), "-o", opts, "-l", str(self.dir / "log"), "-w", "-t", "60", "start")
        self._started = True
        self._run("createdb", "-h", str(self.dir), "-p", str(self.port), "-U", self.role, self.database)
        return self

    @property
    def url(self) -> str:
        """SQLAlchemy URL of the database over the unix socket."""
        return f"postgresql+psycopg://{self.role}@/{self.database}?host={self.dir}&port={self.port}"

    def stop(self) -> None:
        try:
            if self._started:
                self._run("pg_ctl", "-D", str(self.dir / "data"), "-m", "fast", "-w", "stop")
                self._started = False
        finally:
            shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> ThrowawayServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
