"""The panel's users: names, roles and Argon2id password hashes in a file kept out of the repository.

`station panel-user add NAME --role operator|viewer` writes it; the panel
only reads it. No plain password is ever stored or logged.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError

from station.errors import InputError

Role = Literal["operator", "viewer"]
ROLES: tuple[Role, ...] = ("operator", "viewer")
USER_NAME = re.compile(r"^[A-Za-z0-9_.@-]{1,64}$")
MIN_PASSWORD = 8
_HASHER = PasswordHasher()
# Verified against when the name is unknown, so that a wrong name costs as long as a wrong password.
_DUMMY_HASH = _HASHER.hash("not a password of anyone")


class UserError(InputError):
    """A bad user name, role or password, or an unreadable users file."""


@dataclass(frozen=True)
class User:
    """A user as the users file has them; `credential` changes whenever their password hash does (a new
    password, or the user removed and added again: Argon2 salts every hash afresh), so that a login made
    with the old entry is no longer the same user."""

    name: str
    role: Role
    credential: str = field(default="", repr=False)


def credential(password_hash: str) -> str:
    """A fingerprint of a password hash, kept with a login instead of the hash itself."""
    return hashlib.sha256(password_hash.encode()).hexdigest()[:32]


class UserBook:
    """The users file: {"users": {name: {"role": ..., "hash": ...}}}."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._users: dict[str, dict] = self._read()

    def _read(self) -> dict[str, dict]:
        if not self.path.exists():
            return {}
        try:
            users = json.loads(self.path.read_text())["users"]
        except (ValueError, KeyError, TypeError) as exc:
            raise UserError(f"{self.path}: not a users file ({exc})") from None
        if not isinstance(users, dict) or not all(
            isinstance(u, dict) and u.get("role") in ROLES and isinstance(u.get("hash"), str) for u in users.values()
        ):
            raise UserError(f"{self.path}: every user needs a role ({', '.join(ROLES)}) and a password hash")
        return users

    def _write(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_suffix(".tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as f:
            json.dump({"users": self._users}, f, indent=2)
        os.replace(tmp, self.path)

    def __len__(self) -> int:
        return len(self._users)

    def list(self) -> list[User]:
        return [self._user(name) for name in sorted(self._users)]

    def _user(self, name: str) -> User:
        entry = self._users[name]
        return User(name, entry["role"], credential(entry["hash"]))

    def add(self, name: str, role: str, password: str) -> User:
        """Add a user or replace one's role and password."""
        if not USER_NAME.match(name):
            raise UserError(f"user name {name!r}: use 1-64 letters, digits and _ . @ -")
        if role not in ROLES:
            raise UserError(f"role {role!r}: allowed {', '.join(ROLES)}")
        if len(password) < MIN_PASSWORD:
            raise UserError(f"password too short: at least {MIN_PASSWORD} characters")
        self._users[name] = {"role": role, "hash": _HASHER.hash(password)}
        self._write()
        return self._user(name)

    def remove(self, name: str) -> None:
        if self._users.pop(name, None) is None:
            raise UserError(f"no user {name!r} in {self.path}")
        self._write()

    def verify(self, name: str, password: str) -> User | None:
        """The user if the password is right; None otherwise (unknown names take as long)."""
        entry = self._users.get(name)
        try:
            _HASHER.verify(entry["hash"] if entry else _DUMMY_HASH, password)
        except (VerificationError, InvalidHashError):
            return None
        return self._user(name) if entry else None


class LiveUsers:
    """The users file as it is now, for the panel's every request: re-read whenever it changes on disk (inode,
    size or mtime), so that a removed user, a changed role or a changed password takes effect on the next
    request."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._stamp: tuple[int, int, int] | None = None
        self._users: dict[str, User] = {}

    def current(self, name: str) -> User | None:
        """The user as the file has them now; None once removed (or if the file is gone or unreadable)."""
        try:
            st = self.path.stat()
            stamp = (st.st_ino, st.st_size, st.st_mtime_ns)
        except OSError:
            return None
        with self._lock:
            if stamp != self._stamp:
                try:
                    self._users = {u.name: u for u in UserBook(self.path).list()}
                except UserError:
                    self._users = {}
                self._stamp = stamp
            return self._users.get(name)
