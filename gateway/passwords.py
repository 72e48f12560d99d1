"""Console passwords and API tokens, stored as hashes only.

A password is hashed with scrypt (the standard library's, memory-hard) and a random salt per
user: `scrypt$16384$8$1$<salt>$<hash>` (base64). An API token is 32 random bytes, so it can't be
guessed and needs no slow hash: `sha256$<hex>`. A check takes the same time whatever matches.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import secrets
from typing import Final

SCRYPT_N: Final = 2**14
SCRYPT_R: Final = 8
SCRYPT_P: Final = 1
SALT_BYTES: Final = 16
HASH_BYTES: Final = 32
TOKEN_BYTES: Final = 32
_SCRYPT_MAX_N: Final = 2**20
"""A hash asking for more would take seconds and a gigabyte per login: refused at load."""


def hash_password(password: str, salt: bytes | None = None) -> str:
    salt = secrets.token_bytes(SALT_BYTES) if salt is None else salt
    digest = _scrypt(password, salt, SCRYPT_N, SCRYPT_R, SCRYPT_P)
    return f"scrypt${SCRYPT_N}${SCRYPT_R}${SCRYPT_P}${_b64(salt)}${_b64(digest)}"


def verify_password(password: str, stored: str) -> bool:
    """Whether `password` is the one `stored` was made from (slow on purpose: run it in a
    thread, never on the event loop)."""
    n, r, p, salt, digest = _parse_scrypt(stored)
    return hmac.compare_digest(_scrypt(password, salt, n, r, p), digest)


def new_token() -> str:
    return secrets.token_urlsafe(TOKEN_BYTES)


def hash_token(token: str) -> str:
    return "sha256$" + hashlib.sha256(token.encode()).hexdigest()


def token_matches(token: str, stored: str) -> bool:
    return hmac.compare_digest(hash_token(token), stored)


def check_password_hash(stored: str) -> None:
    """ValueError naming what is wrong when `stored` is no password hash this module makes."""
    _parse_scrypt(stored)


def check_token_hash(stored: str) -> None:
    digest = stored.removeprefix("sha256$")
    if digest == stored or len(digest) != 64 or any(c not in "0123456789abcdef" for c in digest):
        raise ValueError(
            "not a token hash (sha256$ and 64 hex digits): make one with "
            "`invt-gateway hash-password --new-token`; never put the token itself here"
        )


def _parse_scrypt(stored: str) -> tuple[int, int, int, bytes, bytes]:
    parts = stored.split("$")
    if len(parts) != 6 or parts[0] != "scrypt":
        raise ValueError(
            "not a password hash (scrypt$N$r$p$salt$hash): make one with "
            "`invt-gateway hash-password`; never put the password itself here"
        )
    try:
        n, r, p = int(parts[1]), int(parts[2]), int(parts[3])
        salt, digest = _unb64(parts[4]), _unb64(parts[5])
    except ValueError as exc:
        raise ValueError(f"a damaged password hash: {exc}") from None
    if not (2 <= n <= _SCRYPT_MAX_N and n & (n - 1) == 0 and 1 <= r <= 32 and 1 <= p <= 16):
        raise ValueError(f"scrypt parameters N={n} r={r} p={p} out of range")
    if len(salt) < 8 or len(digest) < 16:
        raise ValueError("a damaged password hash: salt or hash too short")
    return n, r, p, salt, digest


def _scrypt(password: str, salt: bytes, n: int, r: int, p: int) -> bytes:
    memory = 128 * n * r * p + 2**20
    return hashlib.scrypt(
        password.encode(), salt=salt, n=n, r=r, p=p, maxmem=memory, dklen=HASH_BYTES
    )


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode().rstrip("=")


def _unb64(text: str) -> bytes:
    try:
        return base64.b64decode(text + "=" * (-len(text) % 4), validate=True)
    except (ValueError, TypeError):
        raise ValueError("not base64") from None
