"""A throwaway PostgreSQL server for the tests: Debian's ``postgresql`` binaries (``initdb``,
``pg_ctl``) run into a temporary directory on a free loopback port, as the ``postgres`` user when
the tests run as root (PostgreSQL refuses to run as root).  Tests that need it skip with a message
when the binaries are not installed (``apt-get install postgresql``; .ci/run installs them)."""

from __future__ import annotations

import os
import pwd
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import pytest

__all__ = ["PostgresServer", "pg_bin"]


def pg_bin() -> Path | None:
    """The newest installed PostgreSQL's bin directory (with initdb and pg_ctl), or None."""
    found = []
    for base in sorted(Path("/usr/lib/postgresql").glob("*/bin")):
        if (base / "initdb").exists() and (base / "pg_ctl").exists():
            try:
                found.append((int(base.parent.name), base))
            except ValueError:
                continue
    if found:
        return max(found)[1]
    initdb = shutil.which("initdb")
    return Path(initdb).parent if initdb and shutil.which("pg_ctl") else None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class PostgresServer:
    """A PostgreSQL cluster in a temporary directory on 127.0.0.1:PORT (``start``, ``stop``,
    ``restart``, ``url(db)``, ``create_database(name)``)."""

    def __init__(self, bin_dir: Path):
        self.bin = bin_dir
        self.port = _free_port()
        self.root = Path(tempfile.mkdtemp(prefix="mptrack-pg-"))
        self.data = self.root / "data"
        self.log = self.root / "postgres.log"
        self._user = None
        if os.geteuid() == 0:
            try:
                self._user = pwd.getpwnam("postgres")
            except KeyError:
                raise RuntimeError("running as root and there is no postgres user to run PostgreSQL as") from None
            os.chown(self.root, self._user.pw_uid, self._user.pw_gid)
        self.user = self._user.pw_name if self._user else pwd.getpwuid(os.geteuid()).pw_name
        self._run("initdb", "-D", str(self.data), "-A", "trust", "-U", self.user, "-E", "UTF8", "--no-sync")
        conf = self.data / "postgresql.conf"
        with open(conf, "a") as f:
            # crash safety as in production (WAL written at commit), without flushes to disk (test speed)
            f.write(f"\nport = {self.port}\nlisten_addresses = '127.0.0.1'\nunix_socket_directories = '{self.root}'\n"
                    "fsync = off\nfull_page_writes = off\nshared_buffers = 64MB\nmax_connections = 200\n")

    def _run(self, tool: str, *args: str, check: bool = True) -> subprocess.CompletedProcess:
        def demote():
            if self._user is not None:
                os.setgid(self._user.pw_gid)
                os.setuid(self._user.pw_uid)
        proc = subprocess.run([str(self.bin / tool), *args], capture_output=True, text=True, preexec_fn=demote,
                              cwd=self.root, timeout=120)
        if check and proc.returncode != 0:
            raise RuntimeError(f"{tool} failed ({proc.returncode}): {proc.stderr or proc.stdout}")
        return proc

    def start(self) -> "PostgresServer":
        self._run("pg_ctl", "-D", str(self.data), "-l", str(self.log), "-w", "-t", "60", "start")
        return self

    def stop(self, mode: str = "fast", check: bool = False) -> None:
        """``mode`` immediate is a crash (no shutdown checkpoint; the WAL replays at the next start);
        ``check``: raise if the server was not running or did not stop."""
        self._run("pg_ctl", "-D", str(self.data), "-m", mode, "-w", "stop", check=check)

    def restart(self, mode: str = "fast") -> None:
        self.stop(mode)
        self.start()

    def url(self, db: str = "postgres") -> str:
        return f"postgresql://{self.user}@127.0.0.1:{self.port}/{db}"

    def create_database(self, name: str) -> str:
        """A new empty database; returns its URL."""
        import psycopg

        with psycopg.connect(self.url(), autocommit=True) as con:
            con.execute(f'CREATE DATABASE "{name}"')
        return self.url(name)

    def cleanup(self) -> None:
        self.stop("immediate")
        shutil.rmtree(self.root, ignore_errors=True)


def postgres_or_skip() -> PostgresServer:
    """A started server, or pytest.skip with the reason."""
    bin_dir = pg_bin()
    if bin_dir is None:
        pytest.skip("PostgreSQL is not installed (Debian: apt-get install postgresql); the PostgreSQL tests need "
                    "its initdb and pg_ctl")
    try:
        import psycopg  # noqa: F401
    except ImportError:
        pytest.skip("psycopg is not installed (pip install -e '.[postgresql]')")
    return PostgresServer(bin_dir).start()
