"""A Modbus/TCP Security client's role, from its certificate.

The Modbus Organization's TLS profile (MB-TCP-Security, R-21/R-22) carries the client's role in an
X.509v3 extension, OID 1.3.6.1.4.1.50316.802.1, whose value is an ASN.1 UTF8String ("operator",
"viewer", or a site's own names). Python's `ssl` doesn't show unknown extensions, so the
certificate is read with `cryptography`'s X.509 API (the TLS handshake has already verified it
against the configured CA); an extension the library doesn't know comes back as its raw value,
the UTF8String's DER, read here. Certificates without the extension can be given a role by their
subject's common name (`role_map`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Final

from cryptography import x509

ROLE_OID: Final = "1.3.6.1.4.1.50316.802.1"
_ROLE: Final = x509.ObjectIdentifier(ROLE_OID)
_UTF8_STRING: Final = 0x0C


def role_extension(certificate_der: bytes) -> str | None:
    """The role extension's value, or None when the certificate has none (or is unreadable)."""
    try:
        certificate = x509.load_der_x509_certificate(certificate_der)
        value = certificate.extensions.get_extension_for_oid(_ROLE).value
    except (ValueError, x509.ExtensionNotFound):  # not DER, or extensions that can't be parsed
        return None
    if not isinstance(value, x509.UnrecognizedExtension):
        return None
    return _utf8_string(value.value)


def _utf8_string(der: bytes) -> str | None:
    """The text of a DER UTF8String (tag 0CH, a short or long length, the bytes), or None."""
    if len(der) < 2 or der[0] != _UTF8_STRING:
        return None
    length, start = der[1], 2
    if length & 0x80:  # long form: the next (length & 7FH) bytes give the length
        start += length & 0x7F
        length = int.from_bytes(der[2:start], "big")
    if start + length != len(der):
        return None
    return der[start:].decode("utf-8", errors="replace")


def common_name(peer: Mapping[str, object] | None) -> str | None:
    """The subject's CN from `SSLObject.getpeercert()`."""
    if not peer:
        return None
    subject = peer.get("subject", ())
    if not isinstance(subject, tuple):
        return None
    for rdn in subject:
        for key, value in rdn:
            if key == "commonName":
                return str(value)
    return None


def client_role(
    certificate_der: bytes | None,
    peer: Mapping[str, object] | None,
    role_map: Mapping[str, str],
) -> str | None:
    """The role in the certificate's extension; else the one `role_map` gives its common name."""
    if certificate_der:
        role = role_extension(certificate_der)
        if role:
            return role
    name = common_name(peer)
    return role_map.get(name) if name is not None else None
