"""Throw-away TLS material made with the `openssl` command, and a Mosquitto that demands it.

A test CA signs a server certificate for 127.0.0.1 and a client certificate; the broker listens
with TLS only, wants a client certificate signed by that CA *and* a username and password from
its password file (made with `mosquitto_passwd`), and admits no anonymous client.
"""

from __future__ import annotations

import os
import shutil
import ssl
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.support.mosquitto import Mosquitto

USERNAME = "plant-gateway"
PASSWORD = "s3cret-for-tests"
DAYS = "2"
CURVE = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]


@dataclass(frozen=True)
class Certificates:
    ca: Path
    server_cert: Path
    server_key: Path
    client_cert: Path
    client_key: Path

    def client_context(self) -> ssl.SSLContext:
        context = ssl.create_default_context(cafile=str(self.ca))
        context.load_cert_chain(str(self.client_cert), str(self.client_key))
        return context


def make_certificates(directory: Path) -> Certificates:
    if shutil.which("openssl") is None:
        pytest.fail("the openssl command is needed for the TLS tests (Debian package openssl)")

    def openssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=directory, check=True, capture_output=True)

    openssl(
        "req",
        "-x509",
        *CURVE,
        "-keyout",
        "ca.key",
        "-out",
        "ca.pem",
        "-days",
        DAYS,
        "-subj",
        "/CN=invt-gateway test CA",
    )
    for name, extensions in (
        ("server", "subjectAltName=IP:127.0.0.1,DNS:localhost\nextendedKeyUsage=serverAuth\n"),
        ("client", "extendedKeyUsage=clientAuth\n"),
    ):
        (directory / f"{name}.ext").write_text(extensions, encoding="utf-8")
        openssl(
            "req", *CURVE, "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN={name}"
        )
        openssl(
            "x509",
            "-req",
            "-in",
            f"{name}.csr",
            "-CA",
            "ca.pem",
            "-CAkey",
            "ca.key",
            "-CAcreateserial",
            "-out",
            f"{name}.pem",
            "-days",
            DAYS,
            "-extfile",
            f"{name}.ext",
        )
    return Certificates(
        directory / "ca.pem",
        directory / "server.pem",
        directory / "server.key",
        directory / "client.pem",
        directory / "client.key",
    )


class TlsMosquitto(Mosquitto):
    """TLS only, client certificate required, username and password required."""

    def __init__(self, directory: Path, certificates: Certificates) -> None:
        super().__init__(directory)
        passwords = directory / "passwords"
        subprocess.run(
            ["mosquitto_passwd", "-b", "-c", str(passwords), USERNAME, PASSWORD],
            check=True,
            capture_output=True,
        )
        # Started as root, Mosquitto would become user "mosquitto", who can't read a test's
        # private temporary directory; as anyone else it stays who it is.
        user = "user root\n" if os.geteuid() == 0 else ""
        self.config_file.write_text(
            f"{user}listener {self.port} {self.host}\n"
            f"cafile {certificates.ca}\n"
            f"certfile {certificates.server_cert}\n"
            f"keyfile {certificates.server_key}\n"
            "require_certificate true\n"
            "allow_anonymous false\n"
            f"password_file {passwords}\n"
            "persistence false\n"
            f"log_dest file {self.log_file}\n",
            encoding="utf-8",
        )


ROLE_EXTENSION = "1.3.6.1.4.1.50316.802.1"
"""Modbus/TCP Security's role extension: an ASN.1 UTF8String in the client certificate."""


def make_ca(directory: Path, name: str) -> tuple[Path, Path]:
    """A throw-away CA: (certificate, key)."""
    subprocess.run(
        [
            *("openssl", "req", "-x509", *CURVE, "-keyout", f"{name}.key", "-out", f"{name}.pem"),
            *("-days", DAYS, "-subj", f"/CN=invt-gateway {name}"),
        ],
        cwd=directory,
        check=True,
        capture_output=True,
    )
    return directory / f"{name}.pem", directory / f"{name}.key"


def make_signed(
    directory: Path, name: str, ca: tuple[Path, Path], extensions: str
) -> tuple[Path, Path]:
    """A certificate for CN=`name` signed by `ca`, with `extensions` (openssl's -extfile)."""
    (directory / f"{name}.ext").write_text(extensions, encoding="utf-8")

    def openssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=directory, check=True, capture_output=True)

    openssl("req", *CURVE, "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN={name}")
    openssl(
        "x509", "-req", "-in", f"{name}.csr", "-CA", str(ca[0]), "-CAkey", str(ca[1]),
        "-CAcreateserial", "-out", f"{name}.pem", "-days", DAYS, "-extfile", f"{name}.ext",
    )  # fmt: skip
    return directory / f"{name}.pem", directory / f"{name}.key"


def client_with_role(directory: Path, name: str, ca: tuple[Path, Path], role: str | None):  # type: ignore[no-untyped-def]
    """A client certificate carrying Modbus/TCP Security's role extension (none if `role` is
    None)."""
    extensions = "extendedKeyUsage=clientAuth\n"
    if role is not None:
        extensions += f"{ROLE_EXTENSION}=ASN1:UTF8String:{role}\n"
    return make_signed(directory, name, ca, extensions)
