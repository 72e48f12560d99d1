"""A Modbus/TCP Security client's role, as pure functions: read from the role extension
(OID 1.3.6.1.4.1.50316.802.1, a UTF8String) of the certificate's DER, else from the subject's
common name through `role_map`, else none. The TLS tests read it from real openssl certificates;
these walk hand-built DER, including broken DER that must never raise."""

from __future__ import annotations

import pytest

from gateway.tcp.cert_roles import ROLE_OID, client_role, encode_oid, role_extension


def tlv(tag: int, value: bytes) -> bytes:
    length = len(value)
    if length < 0x80:
        return bytes((tag, length)) + value
    size = (length.bit_length() + 7) // 8
    return bytes((tag, 0x80 | size)) + length.to_bytes(size, "big") + value


def certificate(*extensions: bytes) -> bytes:
    """Certificate { TBSCertificate { version, serial, ..., [3] { Extensions } }, ... }: what the
    walker looks at, with filler where a real certificate has its other fields."""
    version = tlv(0xA0, tlv(0x02, b"\x02"))
    serial = tlv(0x02, b"\x01")
    subject = tlv(0x30, b"\x00" * 150)  # a long field: two-byte DER lengths on the way
    tbs = version + serial + subject
    if extensions:
        tbs += tlv(0xA3, tlv(0x30, b"".join(extensions)))
    return tlv(0x30, tlv(0x30, tbs) + tlv(0x30, b"") + tlv(0x03, b"\x00"))


def extension(oid: str, value: bytes) -> bytes:
    return tlv(0x30, tlv(0x06, encode_oid(oid)) + tlv(0x04, value))


def role(name: str) -> bytes:
    return extension(ROLE_OID, tlv(0x0C, name.encode()))


KEY_USAGE = extension("2.5.29.15", tlv(0x03, b"\x05\xa0"))
PEER = {"subject": ((("organizationName", "Plant"),), (("commonName", "scada-1"),))}


def test_oids_are_encoded_as_der_writes_them() -> None:
    assert encode_oid("1.2.840.113549") == bytes.fromhex("2A 86 48 86 F7 0D")  # RSA's arc
    assert encode_oid(ROLE_OID) == bytes.fromhex("2B 06 01 04 01 83 89 0C 86 22 01")


def test_the_role_is_the_extensions_utf8_string_among_others() -> None:
    assert role_extension(certificate(KEY_USAGE, role("operator"))) == "operator"
    assert role_extension(certificate(role("Betreiber-Süd"))) == "Betreiber-Süd"


def test_a_certificate_without_the_role_has_none() -> None:
    assert role_extension(certificate(KEY_USAGE)) is None
    assert role_extension(certificate()) is None
    not_a_string = extension(ROLE_OID, tlv(0x02, b"\x01"))
    assert role_extension(certificate(not_a_string)) is None


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
