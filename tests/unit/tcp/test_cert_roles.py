"""A Modbus/TCP Security client's role, as pure functions: read from the role extension
(OID 1.3.6.1.4.1.50316.802.1, a UTF8String) of the certificate, else from the subject's common
name through `role_map`, else none. The certificates here are made with `cryptography`, as a CA's
tooling makes them; the TLS tests read roles from real openssl certificates over a handshake."""

from __future__ import annotations

import datetime

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.serialization import Encoding
from cryptography.x509.oid import NameOID

from gateway.tcp.cert_roles import ROLE_OID, client_role, role_extension

KEY = ec.generate_private_key(ec.SECP256R1())
PEER = {"subject": ((("organizationName", "Plant"),), (("commonName", "scada-1"),))}


def der_string(tag: int, text: bytes) -> bytes:
    """A DER string: short form below 128 bytes, long form above (as a CA writes them)."""
    if len(text) < 0x80:
        return bytes((tag, len(text))) + text
    size = (len(text).bit_length() + 7) // 8
    return bytes((tag, 0x80 | size)) + len(text).to_bytes(size, "big") + text


def certificate(*extensions: x509.ExtensionType) -> bytes:
    """A self-signed client certificate for scada-1 with these extensions, as DER."""
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "scada-1")])
    now = datetime.datetime.now(datetime.UTC)
    builder = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(KEY.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(now + datetime.timedelta(days=1))
    )
    for extension in extensions:
        builder = builder.add_extension(extension, critical=False)
    # DER, as `ssl` hands over the peer's certificate.
    return builder.sign(KEY, hashes.SHA256()).public_bytes(Encoding.DER)


def role(text: str) -> x509.UnrecognizedExtension:
    return x509.UnrecognizedExtension(
        x509.ObjectIdentifier(ROLE_OID), der_string(0x0C, text.encode())
    )


KEY_USAGE = x509.KeyUsage(
    digital_signature=True,
    content_commitment=False,
    key_encipherment=True,
    data_encipherment=False,
    key_agreement=False,
    key_cert_sign=False,
    crl_sign=False,
    encipher_only=False,
    decipher_only=False,
)


def test_the_role_is_the_extensions_utf8_string_among_others() -> None:
    assert role_extension(certificate(KEY_USAGE, role("operator"))) == "operator"
    assert role_extension(certificate(role("Betreiber-Süd"))) == "Betreiber-Süd"
    long_name = "plant-north-" + "x" * 200  # a two-byte DER length
    assert role_extension(certificate(role(long_name))) == long_name


def test_a_certificate_without_the_role_has_none() -> None:
    assert role_extension(certificate(KEY_USAGE)) is None
    assert role_extension(certificate()) is None
    not_a_string = x509.UnrecognizedExtension(x509.ObjectIdentifier(ROLE_OID), b"\x02\x01\x01")
    assert role_extension(certificate(not_a_string)) is None
    cut_short = x509.UnrecognizedExtension(x509.ObjectIdentifier(ROLE_OID), b"\x0c\x05abc")
    assert role_extension(certificate(cut_short)) is None


@pytest.mark.parametrize("cut", [1, 2, 5, 40, 180])
def test_broken_der_is_no_role_not_a_crash(cut: int) -> None:
    whole = certificate(role("operator"))
    assert role_extension(whole[:cut]) is None
    assert role_extension(b"\x30\x85\x00\x00\x00\x00\x01") is None  # a five-byte length


def test_the_extension_wins_then_the_common_name_then_nothing() -> None:
    role_map = {"scada-1": "viewer"}
    assert client_role(certificate(role("operator")), PEER, role_map) == "operator"
    assert client_role(certificate(KEY_USAGE), PEER, role_map) == "viewer"
    assert client_role(None, PEER, {}) is None
    assert client_role(None, None, role_map) is None
