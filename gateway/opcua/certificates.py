"""The server's application certificate, and the clients' certificates trusted or refused.

The certificate is made once, on the first start that finds none (`opcua.certificate_file`
left out), and kept: a client trusts the server by this very certificate, so a new one at every
start would have every SCADA refuse the gateway after each restart. Its SHA-1 thumbprint (what
UaExpert and Ignition show beside a certificate) is logged at every start.

A client is trusted by its exact certificate, as a file in the trusted folder: no chains, no
revocation lists in this version. A certificate not there is refused (BadCertificateUntrusted)
and written to the rejected folder as `<thumbprint>.der`, for an admin to move it over; the
trusted folder is read again at each new session, so no restart is needed.
"""

from __future__ import annotations

import datetime
import ipaddress
import logging
import os
import socket
from pathlib import Path
from typing import Final

from asyncua import ua
from asyncua.common.utils import ServiceError
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

log = logging.getLogger(__name__)

KEY_BITS: Final = 2048
"""What Basic256Sha256 asks for (2048 to 4096 bits)."""
VALID_DAYS: Final = 3650
KEY_USAGE: Final = x509.KeyUsage(
    digital_signature=True,
    content_commitment=True,
    key_encipherment=True,
    data_encipherment=True,
    key_agreement=False,
    key_cert_sign=True,
    crl_sign=False,
    encipher_only=False,
    decipher_only=False,
)
"""OPC UA Part 6: the usages a client checks of an application instance certificate."""


def thumbprint(certificate: x509.Certificate) -> str:
    """SHA-1 of the DER form, in hex: how OPC UA tools name a certificate."""
    return certificate.fingerprint(hashes.SHA1()).hex()


def load_certificate(path: Path) -> x509.Certificate:
    data = path.read_bytes()
    if data.lstrip().startswith(b"-----BEGIN"):
        return x509.load_pem_x509_certificate(data)
    return x509.load_der_x509_certificate(data)


def ensure_server_certificate(
    certificate_file: Path, key_file: Path, application_uri: str, name: str, host: str
) -> x509.Certificate:
    """The server's certificate, made (with its key) when `certificate_file` is absent: for
    this host's name, and for `host` (the endpoint's) where it is an address, not 0.0.0.0."""
    if not certificate_file.exists():
        _make(certificate_file, key_file, _alternative_names(application_uri, host), name)
        log.warning("OPC UA: made the server certificate %s", certificate_file)
    return load_certificate(certificate_file)


def _alternative_names(application_uri: str, host: str) -> x509.SubjectAlternativeName:
    """OPC UA Part 6: the application URI, and the names a client may reach the server by
    (a client compares the endpoint's host with them)."""
    names: list[x509.GeneralName] = [
        x509.UniformResourceIdentifier(application_uri),
        x509.DNSName(socket.gethostname()),
        x509.DNSName("localhost"),
    ]
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        names.append(x509.DNSName(host))
    else:
        if not address.is_unspecified:
            names.append(x509.IPAddress(address))
    return x509.SubjectAlternativeName(names)


def _make(
    certificate_file: Path, key_file: Path, alternative: x509.SubjectAlternativeName, name: str
) -> None:
    key = rsa.generate_private_key(public_exponent=65537, key_size=KEY_BITS)
    subject = x509.Name(
        [
            x509.NameAttribute(NameOID.COMMON_NAME, name),
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, "invt-gateway"),
        ]
    )
    now = datetime.datetime.now(datetime.UTC)
    purposes = x509.ExtendedKeyUsage(
        [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
    )
    certificate = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(days=1))
        .not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
        .add_extension(alternative, critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(KEY_USAGE, critical=True)
        .add_extension(purposes, critical=False)
        .sign(key, hashes.SHA256())
    )
    certificate_file.parent.mkdir(parents=True, exist_ok=True)
    pem = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.TraditionalOpenSSL,
        serialization.NoEncryption(),
    )
    # The key readable by the gateway's user alone, from its first byte on disk.
    descriptor = os.open(key_file, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(descriptor, "wb") as out:
        out.write(pem)
    certificate_file.write_bytes(certificate.public_bytes(serialization.Encoding.DER))


class ClientTrust:
    """The server's check of a client's certificate at CreateSession (asyncua's
    `CertificateValidatorMethod`)."""

    def __init__(self, trusted: Path, rejected: Path) -> None:
        self.trusted = trusted
        self.rejected = rejected
        trusted.mkdir(parents=True, exist_ok=True)
        rejected.mkdir(parents=True, exist_ok=True)

    async def __call__(
        self, certificate: x509.Certificate, application: ua.ApplicationDescription
    ) -> None:
        if certificate in self._trusted():
            now = datetime.datetime.now(datetime.UTC)
            if not certificate.not_valid_before_utc <= now <= certificate.not_valid_after_utc:
                raise ServiceError(ua.StatusCodes.BadCertificateTimeInvalid)
            return
        name = thumbprint(certificate)
        kept = self.rejected / f"{name}.der"
        kept.write_bytes(certificate.public_bytes(serialization.Encoding.DER))
        log.warning(
            "OPC UA: refused the untrusted certificate %s of %s (%s); move %s to %s to trust it",
            name,
            application.ApplicationUri,
            certificate.subject.rfc4514_string(),
            kept,
            self.trusted,
        )
        raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)

    def _trusted(self) -> list[x509.Certificate]:
        found = []
        for path in sorted(self.trusted.iterdir()):
            try:
                found.append(load_certificate(path))
            except (OSError, ValueError) as exc:
                log.warning("OPC UA: %s is no certificate (%s): ignored", path, exc)
        return found
