"""The secrets of a kept configuration version, sealed with a key of this box's.

Each version the console's editor keeps is a whole configuration text (for its diff and a
rollback), and the store is a file that gets copied: backups, a support request, a box sent for
repair. So a secret's value is never kept as it is: it is encrypted (AES-256-GCM, a fresh nonce
each time) and kept as one quoted string, `"sealed:v1:<base64url of nonce and ciphertext>"`,
where the value was. The console shows it masked like any secret; a rollback opens it again.

The key is a file of its own beside the store, `<storage.path>.secrets-key` (mode 0600, made at
the first seal): the backup recipe copies the store alone, so a copy's secrets can't be read
without the box. A store kept in memory only (its file could not be opened) gets a key in
memory: its versions go with the process anyway. A version sealed with another key (the store
moved to another box, the key file removed) can't be opened: its rollback is refused, saying so.
"""

from __future__ import annotations

import base64
import os
import re
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Final

from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives.ciphers.aead import AESGCM

from gateway.errors import EditRefused

PREFIX: Final = "sealed:v1:"
KEY_SUFFIX: Final = ".secrets-key"
NONCE_BYTES: Final = 12
KEY_BYTES: Final = 32
SEALED: Final = re.compile(r"""(["']?)sealed:v1:(?P<data>[A-Za-z0-9_-]+={0,2})\1""")
"""A sealed value as the text has it (quoted, as `seal` writes it, or not)."""


class SecretSeal:
    """Seals and opens secret values with the box's key, made or read at first use."""

    def __init__(self, store_path: Callable[[], str | None]) -> None:
        """`store_path`: the store's file now (None: the store is in memory only)."""
        self.store_path = store_path
        self._key: bytes | None = None
        self._making = threading.Lock()
        """Two first uses at once (a rollback and an apply, each on a thread of its own) make or
        read the key file one after the other: never one reading it half-written."""

    def seal(self, value: str) -> str:
        """`value` (as the text has it, quotes included) as one quoted sealed string."""
        nonce = os.urandom(NONCE_BYTES)
        data = nonce + AESGCM(self._the_key()).encrypt(nonce, value.encode(), None)
        return f'"{PREFIX}{base64.urlsafe_b64encode(data).decode()}"'

    def open_all(self, text: str, what: str) -> str:
        """`text` with every sealed value back as it was; `EditRefused` (409) naming `what`
        when one was sealed with another key."""
        aead = AESGCM(self._the_key())

        def opened(match: re.Match[str]) -> str:
            data = base64.urlsafe_b64decode(match["data"])
            try:
                return aead.decrypt(data[:NONCE_BYTES], data[NONCE_BYTES:], None).decode()
            except (InvalidTag, ValueError):
                raise EditRefused(
                    409,
                    f"{what}: its secrets were sealed with another key than this box's "
                    f"({self._key_file() or 'in memory'}): it can't be applied again; edit the "
                    "current configuration instead",
                ) from None

        return SEALED.sub(opened, text)

    def _key_file(self) -> str | None:
        path = self.store_path()
        return None if path is None else path + KEY_SUFFIX

    def _the_key(self) -> bytes:
        with self._making:
            if self._key is None:
                path = self._key_file()
                if path is None:
                    self._key = AESGCM.generate_key(KEY_BYTES * 8)
                else:
                    self._key = _load_or_make(Path(path))
            return self._key


def _load_or_make(path: Path) -> bytes:
    """The key in `path`, made there first if there is none (0600, never over another's)."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
    except FileExistsError:
        return _read_key(path)
    key = AESGCM.generate_key(KEY_BYTES * 8)
    with os.fdopen(fd, "wb") as out:
        out.write(base64.b64encode(key) + b"\n")
        out.flush()
        os.fsync(out.fileno())
    return key


def _read_key(path: Path) -> bytes:
    try:
        key = base64.b64decode(path.read_bytes().strip(), validate=True)
    except ValueError:
        key = b""
    if len(key) != KEY_BYTES:
        raise OSError(f"{path}: not a key this gateway made (remove it to make a new one)")
    return key
