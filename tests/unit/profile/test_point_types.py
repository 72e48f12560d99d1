"""Typed points read and written in each word and byte order. The expected registers are
written out by hand from the order's definition (where bytes A B C D of the big-endian value
arrive), not computed by the module."""

from __future__ import annotations

import struct

import pytest

from gateway.profile.point_types import Kind, Order, Table, TypedPoint

# 230.5 as an IEEE 754 float is 43 66 80 00: A=43 B=66 C=80 D=00.
F32_230_5 = {
    Order.ABCD: (0x4366, 0x8000),
    Order.CDAB: (0x8000, 0x4366),
    Order.BADC: (0x6643, 0x0080),
    Order.DCBA: (0x0080, 0x6643),
}


def point(kind: Kind, order: Order = Order.ABCD, **more: object) -> TypedPoint:
    registers = more.pop("registers", None)
    sizes = {Kind.U32: 2, Kind.S32: 2, Kind.F32: 2, Kind.U64: 4, Kind.S64: 4, Kind.F64: 4}
    return TypedPoint(
        "value",
        Table.HOLDING,
        0,
        kind,
        registers=registers or sizes.get(kind, 1),  # type: ignore[arg-type]
        order=order,
        **more,  # type: ignore[arg-type]
    )


@pytest.mark.parametrize("order", list(Order))
def test_a_float_reads_and_writes_in_each_order(order: Order) -> None:
    f32 = point(Kind.F32, order)
    assert f32.decode(F32_230_5[order]) == 230.5
    assert f32.encode(230.5) == F32_230_5[order]


@pytest.mark.parametrize(
    ("order", "words"),
    [
        # 0x0102030405060708: registers 0102 0304 0506 0708 in Modbus's own order.
        (Order.ABCD, (0x0102, 0x0304, 0x0506, 0x0708)),
        (Order.CDAB, (0x0708, 0x0506, 0x0304, 0x0102)),
        (Order.BADC, (0x0201, 0x0403, 0x0605, 0x0807)),
        (Order.DCBA, (0x0807, 0x0605, 0x0403, 0x0201)),
    ],
)
def test_a_64_bit_integer_in_each_order(order: Order, words: tuple[int, ...]) -> None:
    u64 = point(Kind.U64, order)
    assert u64.decode(words) == 0x0102030405060708
    assert u64.encode(0x0102030405060708) == words


def test_signed_types_and_f64() -> None:
    assert point(Kind.S16).decode([0xFFFE]) == -2
    assert point(Kind.S32, Order.CDAB).decode([0xFFFE, 0xFFFF]) == -2
    assert point(Kind.S64).decode([0xFFFF] * 3 + [0xFFFD]) == -3
    f64 = point(Kind.F64)
    words = struct.unpack(">4H", struct.pack(">d", -1.25e10))
    assert f64.decode(words) == -1.25e10


def test_scale_and_offset_apply_both_ways() -> None:
    tenths = point(Kind.S16, scale=0.1, offset=-40.0)
    assert tenths.decode([655]) == pytest.approx(25.5)
    assert tenths.encode(25.5) == (655,)
    assert point(Kind.U16, scale=10).decode([7]) == 70  # stays an integer


def test_a_string_bits_and_an_enumeration() -> None:
    text = point(Kind.STRING, registers=4)
    assert text.decode([0x5344, 0x4D36, 0x3330, 0x0000]) == "SDM630"
    assert point(Kind.STRING, Order.BADC, registers=2).decode([0x4453, 0x364D]) == "SDM6"
    assert text.encode("AB") == (0x4142, 0, 0, 0)
    assert point(Kind.BIT, bit=3).decode([0b1000]) is True
    assert point(Kind.BIT, bit=2).decode([0b1000]) is False
    mode = point(Kind.ENUM, values={0: "auto", 1: "manual"})
    assert (mode.decode([1]), mode.decode([7])) == ("manual", "7")
    assert mode.encode("auto") == (0,)


def test_a_value_that_does_not_fit_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match="value = 70000 is outside what a u16 holds"):
        point(Kind.U16).encode(70000)
    with pytest.raises(ValueError, match="must be one of auto"):
        point(Kind.ENUM, values={0: "auto"}).encode("off")
    with pytest.raises(ValueError, match="at most 4 characters"):
        point(Kind.STRING, registers=2).encode("too long")


def test_a_float32_is_published_as_the_decimal_it_was_written_as() -> None:
    # 230.1 as an f32 is 43 66 19 9A, which is 230.10000610351562 as a double.
    words = (0x4366, 0x199A)
    assert point(Kind.F32).decode(words) == 230.1
    assert struct.pack(">f", 230.1) == struct.pack(">2H", *words)  # the same f32


def test_decimals_round_what_a_scale_leaves() -> None:
    assert point(Kind.U16, scale=16 / 65535, offset=4.0, decimals=3).decode([65535]) == 20.0
