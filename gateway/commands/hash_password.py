"""`invt-gateway hash-password`: the `password_hash` (or `token_hash`) of a console user.

The password is asked twice on a terminal, or read as one line from standard input when that is
a pipe (`echo "$PW" | invt-gateway hash-password`), so it never shows in the process list.
`--new-token` makes a random API token instead and prints it with its hash: the token goes to
the script that uses it, the hash into the config.
"""

from __future__ import annotations

import argparse
import getpass
import sys

from gateway.exit_codes import EXIT_FAILURE, EXIT_OK
from gateway.passwords import hash_password, hash_token, new_token

MIN_PASSWORD = 8


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "hash-password",
        help="print the salted hash of a console password (for console.users[].password_hash)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--new-token",
        action="store_true",
        help="make a random API token and print it with its hash (for console.users[].token_hash)",
    )
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    if args.new_token:
        token = new_token()
        print(f"token:      {token}")
        print(f"token_hash: {hash_token(token)}")
        return EXIT_OK
    try:
        password = _read_password()
    except ValueError as exc:
        print(f"invt-gateway hash-password: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    print(hash_password(password))
    return EXIT_OK


def _read_password() -> str:
    if sys.stdin.isatty():
        password = getpass.getpass("password: ")
        if getpass.getpass("again: ") != password:
            raise ValueError("the two passwords differ")
    else:
        password = sys.stdin.readline().rstrip("\r\n")
    if len(password) < MIN_PASSWORD:
        raise ValueError(f"a console password needs at least {MIN_PASSWORD} characters")
    return password
