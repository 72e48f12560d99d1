"""A Modbus/TCP Security client's role, from its certificate.

The Modbus Organization's TLS profile (MB-TCP-Security, R-21/R-22) carries the client's role in an
X.509v3 extension, OID 1.3.6.1.4.1.50316.802.1, whose value is an ASN.1 UTF8String ("operator",
"viewer", or a site's own names). Python's `ssl` doesn't show unknown extensions, so the role is
read from the certificate's DER here: a few lines of DER walking, no crypto (the TLS handshake has
already verified the certificate against the configured CA). Certificates without the extension
can be given a role by their subject's common name (`role_map`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Final

from gateway.errors import MalformedCertificate

ROLE_OID: Final = "1.3.6.1.4.1.50316.802.1"

_SEQUENCE = 0x30
_OID = 0x06
_BOOLEAN = 0x01
_OCTET_STRING = 0x04
_UTF8_STRING = 0x0C
_EXTENSIONS = 0xA3  # [3] EXPLICIT in TBSCertificate


def encode_oid(dotted: str) -> bytes:
    """The DER content bytes of an OBJECT IDENTIFIER ("1.3.6..." without tag and length)."""
    arcs = [int(arc) for arc in dotted.split(".")]
    out = bytearray([40 * arcs[0] + arcs[1]])
    for arc in arcs[2:]:
        chunk = [arc & 0x7F]
        arc >>= 7
        while arc:
            chunk.append(0x80 | (arc & 0x7F))
            arc >>= 7
        out += bytes(reversed(chunk))
    return bytes(out)


_ROLE_OID_BYTES: Final = encode_oid(ROLE_OID)


def _read(data: bytes, offset: int) -> tuple[int, int, int]:
    """(tag, start of the value, end of the value) of the TLV at `offset`."""
    if offset + 2 > len(data):
        raise MalformedCertificate("truncated")
    tag, length = data[offset], data[offset + 1]
    start = offset + 2
    if length & 0x80:
        count = length & 0x7F
        if count == 0 or count > 4 or start + count > len(data):
            raise MalformedCertificate("bad length")
        length = int.from_bytes(data[start : start + count], "big")
        start += count
    end = start + length
    if end > len(data):
        raise MalformedCertificate("truncated")
    return tag, start, end


def _children(data: bytes, start: int, end: int) -> list[tuple[int, int, int]]:
    children = []
    offset = start
    while offset < end:
        tag, value_start, value_end = _read(data, offset)
        children.append((tag, value_start, value_end))
        offset = value_end
    return children


def role_extension(certificate_der: bytes) -> str | None:
    """The role extension's value, or None when the certificate has none (or is unreadable)."""
    try:
        tag, start, end = _read(certificate_der, 0)
        if tag != _SEQUENCE:
            return None
        tbs_tag, tbs_start, tbs_end = _children(certificate_der, start, end)[0]
        if tbs_tag != _SEQUENCE:
            return None
        for tag, value_start, value_end in _children(certificate_der, tbs_start, tbs_end):
            if tag == _EXTENSIONS:
                return _find_role(certificate_der, value_start, value_end)
    except (MalformedCertificate, IndexError):
        return None
    return None


def _find_role(data: bytes, start: int, end: int) -> str | None:
    (tag, list_start, list_end), *_ = _children(data, start, end)
    if tag != _SEQUENCE:
        return None
    for tag, ext_start, ext_end in _children(data, list_start, list_end):
        if tag != _SEQUENCE:
            continue
        parts = _children(data, ext_start, ext_end)
        oid_tag, oid_start, oid_end = parts[0]
        if oid_tag != _OID or data[oid_start:oid_end] != _ROLE_OID_BYTES:
            continue
        value_tag, value_start, _ = parts[-1]
        if value_tag != _OCTET_STRING:
            return None
        inner_tag, text_start, text_end = _read(data, value_start)
        if inner_tag != _UTF8_STRING:
            return None
        return data[text_start:text_end].decode("utf-8", errors="replace")
    return None


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
