"""Scaled values, PMC elements and parameter/diagnosis records: worked examples and round trips."""

from __future__ import annotations

import struct
from decimal import Decimal

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge.focas import values as values_module
from edge.focas.errors import ProtocolError
from edge.focas.model import ParamRecord, ParamType, PmcType
from edge.focas.values import (
    NO_VALUE,
    SCALED_LAYOUT,
    SlotForm,
    decode_pmc,
    decode_records,
    decode_scaled,
    decode_scaled_list,
    encode_pmc,
    encode_records,
    encode_scaled,
    record_stride,
)


@pytest.mark.parametrize("hexbytes,value", [
    ("297c1e00000a0006", 696.0),
    ("05f5e100000a0008", 1.0),
    ("0bc77120000a0006", 197.62),
    ("002f7ae9000a0004", 311.1657),
    ("ffff93cc000a0000", -27700),
    ("0001ee24000a0003", 126.5),
    ("fffffed4000a0003", -0.3),
    ("ffffffff000affff", None),
    ("00000001000affff", None),
    ("00000003000200 02".replace(" ", ""), 0.75),  # base 2: 3 / 2**2
])
def test_scaled_worked_examples(hexbytes: str, value: float | None) -> None:
    assert decode_scaled(bytes.fromhex(hexbytes)) == value


def test_scaled_rejects_impossible_base_unless_lenient() -> None:
    assert decode_scaled(bytes(8)) == 0.0
    data = bytes.fromhex("0000000100070001")
    with pytest.raises(ProtocolError, match="expected base 10 or 2"):
        decode_scaled(data)
    assert decode_scaled(data, strict=False) is None
    with pytest.raises(ProtocolError, match="expected an 8-byte scaled value at offset 0, got 7"):
        decode_scaled(data[:7])


@pytest.mark.parametrize("value,hexbytes", [
    (1.5, "0000000f000a0001"),
    (100.0, "00000064000a0000"),
    (-0.3, "fffffffd000a0001"),
    (0, "00000000000a0000"),
    (None, NO_VALUE.hex()),
])
def test_encoder_uses_the_smallest_exact_exponent(value: float | None, hexbytes: str) -> None:
    assert encode_scaled(value).hex() == hexbytes


def test_encoder_forced_exponent_and_limits() -> None:
    assert encode_scaled(1.5, exponent=3).hex() == "000005dc000a0003"  # HslCommunication's form
    assert decode_scaled(encode_scaled(1 / 3)) == pytest.approx(1 / 3, rel=1e-8)  # rounded to 9 places
    for bad in (float("nan"), float("inf"), 3e10):
        with pytest.raises(ValueError):
            encode_scaled(bad)


# Every decimal whose mantissa at 3 places fits an i32 must survive exactly.
decimals = st.decimals(min_value=Decimal("-2147483.647"), max_value=Decimal("2147483.647"), places=3,
                       allow_nan=False, allow_infinity=False)


@given(decimals)
def test_scaled_round_trip_is_exact_for_short_decimals(value: Decimal) -> None:
    number = float(value)
    assert decode_scaled(encode_scaled(number)) == number


@given(st.binary(min_size=8, max_size=8))
def test_any_eight_bytes_decode_or_raise_protocol_error(data: bytes) -> None:
    try:
        result = decode_scaled(data)
    except ProtocolError:
        assert decode_scaled(data, strict=False) is None
    else:
        assert result is None or isinstance(result, float)


def test_scaled_list_needs_whole_values() -> None:
    assert decode_scaled_list(bytes.fromhex("297c1e00000a000605f5e100000a0008")) == [696.0, 1.0]
    with pytest.raises(ProtocolError, match="multiple of 8"):
        decode_scaled_list(bytes(9))


# ---- PMC ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype,values", [
    (PmcType.BYTE, [0, 255, 65]),
    (PmcType.WORD, [600, -2, 32767]),
    (PmcType.LONG, [-598358, 2**31 - 1]),
    (PmcType.FLOAT, [1.5, -0.25]),
    (PmcType.DOUBLE, [3.141592653589793]),
])
def test_pmc_round_trip(dtype: PmcType, values: list[int | float]) -> None:
    data = encode_pmc(values, dtype)
    assert len(data) == dtype.width * len(values)
    assert decode_pmc(data, dtype) == values


def test_pmc_word_is_big_endian() -> None:
    assert decode_pmc(b"\x02\x58", PmcType.WORD) == [600]
    with pytest.raises(ProtocolError, match="multiple of 4 bytes, got 6"):
        decode_pmc(bytes(6), PmcType.LONG)
    with pytest.raises(ValueError):
        encode_pmc([256], PmcType.BYTE)


@given(st.sampled_from(list(PmcType)), st.binary(max_size=64))
def test_pmc_decode_only_raises_protocol_error(dtype: PmcType, data: bytes) -> None:
    try:
        values = decode_pmc(data, dtype)
    except ProtocolError:
        assert len(data) % dtype.width
    else:
        assert len(values) == len(data) // dtype.width


# ---- records ------------------------------------------------------------------------------------------


def test_stride() -> None:
    assert record_stride(8, SlotForm.FOUR_BYTE) == 40
    assert record_stride(32, SlotForm.SCALED) == 264


def test_four_byte_slots_bit_and_byte_sit_in_the_last_byte() -> None:
    head = struct.pack(">ihh", 3003, 0, ParamType.BIT)
    payload = head + b"\x11\x22\x33\x02" + b"\x30\x30\x32\x32" * 7
    (record,) = decode_records(payload, 8, SlotForm.FOUR_BYTE)
    assert record == ParamRecord(3003, 0, 0, (2,))


def test_four_byte_word_and_two_word_read_the_whole_slot() -> None:
    payload = (struct.pack(">ihhi", 980, -1, 2, -598358) + struct.pack(">i", 7) + bytes(24))
    (record,) = decode_records(payload, 8, SlotForm.FOUR_BYTE)
    assert record.values == (-598358, 7, 0, 0, 0, 0, 0, 0)


def test_diagnosis_records_are_sized_by_the_slot_never_by_the_type_code() -> None:
    """A diagnosis word sent with type 0 or 1 (byte/word on pyfanuc's table, bit/byte for parameters)
    keeps its whole 4-byte value; the 160i-W's type 2 record decodes as in the capture."""
    payload = (struct.pack(">ihhi", 411, 0, 1, 1200) + bytes(28)
               + struct.pack(">ihhi", 308, 0, 0, -300) + bytes(28)
               + bytes.fromhex("0000039600000002001772a330303232203600000000000000000000000000000000000000000000"))
    records = decode_records(payload, 8, SlotForm.FOUR_BYTE, whole_slots=True)
    assert [r.value for r in records] == [1200, -300, 1536675]
    assert encode_records(records, 8, SlotForm.FOUR_BYTE, whole_slots=True)[:8 + 4] == payload[:12]


def test_scaled_slots_give_ints_for_integer_types_and_floats_for_real() -> None:
    real = ParamRecord(1420, -1, ParamType.REAL, (126.5, -0.3, None, 0.0))
    long_ = ParamRecord(6711, 0, ParamType.TWO_WORD, (52638,))
    data = encode_records([real, long_], 4, SlotForm.SCALED)
    assert len(data) == 2 * record_stride(4, SlotForm.SCALED)
    decoded = decode_records(data, 4, SlotForm.SCALED)
    assert decoded == [real, long_]
    assert isinstance(decoded[1].value, int)


def test_records_length_must_match_stride() -> None:
    with pytest.raises(ProtocolError, match="expected records of 40 bytes"):
        decode_records(bytes(41), 8, SlotForm.FOUR_BYTE)
    with pytest.raises(ProtocolError, match="max_axis >= 1"):
        decode_records(b"", 0, SlotForm.FOUR_BYTE)


record_values = {
    ParamType.BIT: st.integers(0, 255),
    ParamType.BYTE: st.integers(0, 255),
    ParamType.WORD: st.integers(-(2**15), 2**15 - 1),
    ParamType.TWO_WORD: st.integers(-(2**31), 2**31 - 1),
}


@st.composite
def records(draw: st.DrawFn, max_axis: int, form: SlotForm) -> ParamRecord:
    ptype = draw(st.sampled_from(list(record_values)))
    axis = draw(st.sampled_from([-1, 0, 1, max_axis]))
    count = max_axis if axis == -1 else 1
    values = tuple(draw(st.lists(record_values[ptype], min_size=count, max_size=count)))
    return ParamRecord(draw(st.integers(0, 2**31 - 1)), axis, int(ptype), values)


@given(st.data(), st.integers(1, 32), st.sampled_from(list(SlotForm)))
def test_records_round_trip(data: st.DataObject, max_axis: int, form: SlotForm) -> None:
    items = data.draw(st.lists(records(max_axis, form), max_size=4))
    assert decode_records(encode_records(items, max_axis, form), max_axis, form) == items


@given(st.binary(max_size=600), st.integers(1, 32), st.sampled_from(list(SlotForm)))
def test_records_decode_only_raises_protocol_error(data: bytes, max_axis: int, form: SlotForm) -> None:
    try:
        decode_records(data, max_axis, form)
    except ProtocolError:
        assert len(data) % record_stride(max_axis, form)


@given(st.one_of(
    st.floats(allow_nan=False, allow_infinity=False),
    st.floats(min_value=-3e9, max_value=3e9),
    st.decimals(min_value=-2_147_483, max_value=2_147_483, places=3, allow_nan=False,
                allow_infinity=False).map(float),
    st.decimals(min_value=-2, max_value=2, places=10, allow_nan=False, allow_infinity=False).map(float),
    st.integers(min_value=-(2**40), max_value=2**40)))
def test_plain_decimal_shortcut_gives_the_decimal_encoding(value: float) -> None:
    """encode_scaled skips Decimal for plain decimals; where it does, the bytes are Decimal's."""
    quick = values_module._plain_decimal(value)
    if quick is not None:
        assert quick == values_module._encode_decimal(value, None)


scaled_chunks = st.one_of(
    st.tuples(st.integers(-2**31, 2**31 - 1), st.integers(0, 255), st.sampled_from([0, 1, 2, 10, 16, 255]),
              st.sampled_from([-1, 0, 1, 3, 4, 9, 64, 65, -3, -64, -65, 300])).map(lambda t: SCALED_LAYOUT.pack(*t)),
    st.binary(min_size=8, max_size=8))


@given(st.lists(scaled_chunks, max_size=12), st.booleans())
def test_property_a_list_decodes_as_its_values_one_by_one(chunks: list[bytes], strict: bool) -> None:
    payload = b"".join(chunks)
    try:
        expected = [decode_scaled(payload, i * 8, strict=strict) for i in range(len(chunks))]
    except ProtocolError as exc:
        with pytest.raises(ProtocolError, match=str(exc)[:30].replace("±", ".").replace("(", ".")):
            decode_scaled_list(payload, strict=strict)
        return
    got = decode_scaled_list(payload, strict=strict)
    assert [repr(v) for v in got] == [repr(v) for v in expected]  # same floats, bit for bit (and NaN-free)
