"""Work-coordinate offsets (cnc_rdzofs): the packed ext layout, its simulator answer and the native refusal."""

from __future__ import annotations

import contextlib
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge import ConfigError
from edge.collect.plan import Group, MachinePlan, StaticInfo, drop_key, metric_values
from edge.config import parse_config
from edge.focas import items as it
from edge.focas import native
from edge.focas import packed as pk
from edge.focas.errors import CncError, NotSupported, OutOfRange, ProtocolError
from edge.focas.function_entry import Context
from edge.focas.model import ModalGCode
from edge.focas.packed import client as packed_client
from edge.focas.values import SlotForm
from edge.samples import MetricType
from edge.service.settings import poll_settings
from edge.sim import packed_server
from edge.sim.state import MachineState

CTX = Context(max_axis=8, slot_form=SlotForm.FOUR_BYTE)


def test_rdzofs_takes_the_next_free_ext_id_and_its_focas_name() -> None:
    assert pk.Command.RDZOFS == 0x400D
    assert pk.command_name(0x400D) == "cnc_rdzofs"


def test_request_is_one_i16_and_answer_is_count_then_f64_per_axis() -> None:
    plan = packed_client.plan_item(it.ReadWorkOffsets(2))
    assert plan.requests == [(pk.Command.RDZOFS, bytes.fromhex("0200"))]
    wire = pk.read_response(pk.encode_floats([-110.125, 2.5]))
    assert wire == bytes.fromhex("0000" "0200") + bytes.fromhex("0000000000885bc0") + bytes.fromhex("0000000000000440")
    assert plan.combine([wire]) == [-110.125, 2.5]


def test_a_short_or_failed_answer_raises() -> None:
    with pytest.raises(ProtocolError):
        pk.decode_work_offsets_response(bytes.fromhex("0000" "0300") + bytes(16))
    with pytest.raises(OutOfRange):
        pk.decode_work_offsets_response(pk.encode_status(3))


@given(st.lists(st.one_of(st.none(), st.floats(allow_nan=False)), max_size=32))
def test_property_work_offsets_round_trip(values: list[float | None]) -> None:
    assert pk.decode_work_offsets_response(pk.read_response(pk.encode_floats(values))) == values


@given(st.binary(max_size=300))
def test_property_decoder_raises_only_typed_errors(payload: bytes) -> None:
    try:
        result = pk.decode_work_offsets_response(payload)
    except (ProtocolError, CncError):
        return
    assert all(v is None or not math.isnan(v) for v in result)


def test_g_codes_map_to_cnc_rdzofs_numbers() -> None:
    assert [it.work_offset_number(g) for g in (54, 59)] == [1, 6]
    with pytest.raises(ValueError, match="G60"):
        it.work_offset_number(60)


def test_native_transport_reports_not_supported_rather_than_guessing_a_wire_form() -> None:
    result = native.item_result(native.plan_item(it.ReadWorkOffsets(1), CTX), [], CTX)
    assert isinstance(result, NotSupported) and "no public" in str(result)


def test_simulator_packed_server_answers_one_value_per_axis_and_refuses_a_bad_number() -> None:
    state = MachineState()
    answer = packed_server.answer(state, pk.Command.RDZOFS, pk.encode_i16(1))
    offsets = pk.decode_work_offsets_response(answer)
    assert len(offsets) == state.profile.axis_count
    assert offsets == state.work_offsets(1) and offsets != state.work_offsets(2)
    with pytest.raises(OutOfRange):
        pk.decode_work_offsets_response(packed_server.answer(state, pk.Command.RDZOFS, pk.encode_i16(99)))


# ---- the poll plan: opt-in, counters period, one Double per axis, dropped per offset ------------------------
WORK_OFFSET_CONFIG = """
mqtt: {host: b, formats: [json]}
machines:
  - id: m1
    host: h
    poll: {work_offsets: [54, 56]}
"""


def test_work_offsets_are_opt_in_and_publish_one_double_per_axis_at_the_counters_period() -> None:
    static = StaticInfo(axis_names=("X", "Y", "B"))
    config = parse_config(WORK_OFFSET_CONFIG, "t", {})
    plan = MachinePlan.build(poll_settings(config.machines[0].poll, config.alarms), static)
    reads = [r for r in plan.reads if isinstance(r.item, it.ReadWorkOffsets)]
    assert [r.item for r in reads] == [it.ReadWorkOffsets(1), it.ReadWorkOffsets(3)]
    assert {r.group for r in reads} == {Group.COUNTERS}
    assert [(s.name, s.type, s.unit) for s in reads[0].metrics] == [
        ("WorkOffset/G54/X", MetricType.DOUBLE, "mm"), ("WorkOffset/G54/Y", MetricType.DOUBLE, "mm"),
        ("WorkOffset/G54/B", MetricType.DOUBLE, "deg")]
    assert [v for _, v in metric_values(reads[1], [1.5, -2.0, 90.0])] == [1.5, -2.0, 90.0]
    assert [r.item for r in plan.without(drop_key(reads[0].item)).reads
            if isinstance(r.item, it.ReadWorkOffsets)] == [it.ReadWorkOffsets(3)]
    default = parse_config(WORK_OFFSET_CONFIG.replace("work_offsets: [54, 56]", "timers: true"), "t", {})
    assert not any(isinstance(r.item, it.ReadWorkOffsets)
                   for r in MachinePlan.build(poll_settings(default.machines[0].poll, default.alarms), static).reads)


@pytest.mark.parametrize("codes", ["[53]", "[60]", "[54, 54]"])
def test_a_work_offset_outside_g54_to_g59_or_twice_is_a_config_error_naming_it(codes: str) -> None:
    with pytest.raises(ConfigError, match="work_offsets"):
        parse_config(WORK_OFFSET_CONFIG.replace("[54, 56]", codes), "t", {})


# ---- modal G codes (0x400E) and the T code in use (0x400F) ------------------------------------------------
def test_modal_and_tool_take_the_next_ext_ids_with_their_focas_names() -> None:
    assert (pk.Command.RDGCODE, pk.Command.RDTOOLNUM) == (0x400E, 0x400F)
    assert (pk.command_name(0x400E), pk.command_name(0x400F)) == ("cnc_rdgcode", "cnc_modal")


def test_modal_g_codes_are_count_then_group_and_8_byte_code() -> None:
    wire = pk.encode_modal_g_codes([ModalGCode(0, "G01"), ModalGCode(13, "G54.1")])
    assert wire == (bytes.fromhex("0200" "0000") + b"G01\x00\x00\x00\x00\x00"
                    + bytes.fromhex("0d00") + b"G54.1\x00\x00\x00")
    plan = packed_client.plan_item(it.ReadModalGCodes())
    assert plan.requests == [(pk.Command.RDGCODE, b"")]
    assert plan.combine([pk.read_response(wire)]) == [ModalGCode(0, "G01"), ModalGCode(13, "G54.1")]
    with pytest.raises(ProtocolError):
        pk.decode_modal_g_codes_response(pk.read_response(wire[:-1]))


def test_tool_number_is_one_i32() -> None:
    plan = packed_client.plan_item(it.ReadToolNumber())
    assert plan.requests == [(pk.Command.RDTOOLNUM, b"")]
    assert plan.combine([pk.read_response(bytes.fromhex("0c000000"))]) == 12


g_codes = st.builds(ModalGCode, st.integers(-(2**15), 2**15 - 1),
                    st.text(alphabet="GM0123456789.", min_size=1, max_size=pk.G_CODE_WIDTH))


@given(st.lists(g_codes, max_size=40))
def test_property_modal_g_codes_round_trip(codes: list[ModalGCode]) -> None:
    assert pk.decode_modal_g_codes_response(pk.read_response(pk.encode_modal_g_codes(codes))) == codes


@given(st.binary(max_size=300))
def test_property_modal_decoder_raises_only_typed_errors(payload: bytes) -> None:
    with contextlib.suppress(ProtocolError, CncError):
        assert all(isinstance(c, ModalGCode) for c in pk.decode_modal_g_codes_response(payload))


@pytest.mark.parametrize("item", [it.ReadModalGCodes(), it.ReadToolNumber()])
def test_native_transport_has_no_wire_form_for_modal_or_tool(item: it.ReadItem) -> None:
    result = native.item_result(native.plan_item(item, CTX), [], CTX)
    assert isinstance(result, NotSupported) and "no public" in str(result)


def test_simulator_answers_modal_codes_and_tool_number() -> None:
    state = MachineState()
    modal = pk.decode_modal_g_codes_response(packed_server.answer(state, pk.Command.RDGCODE, b""))
    assert modal == state.modal_g_codes() and modal[0].code in ("G00", "G01")
    tool = pk.decode_tool_number_response(packed_server.answer(state, pk.Command.RDTOOLNUM, b""))
    assert tool == state.tool_number() and 1 <= tool <= 4


def test_modal_and_tool_number_are_opt_in_counters_reads_with_one_metric_each() -> None:
    config = parse_config(WORK_OFFSET_CONFIG.replace("work_offsets: [54, 56]", "modal: true, tool_number: true"),
                          "t", {})
    plan = MachinePlan.build(poll_settings(config.machines[0].poll, config.alarms), StaticInfo(axis_names=("X",)))
    by_item = {type(r.item).__name__: r for r in plan.reads}
    modal, tool = by_item["ReadModalGCodes"], by_item["ReadToolNumber"]
    assert modal.group is Group.COUNTERS and tool.group is Group.COUNTERS
    assert [(s.name, s.type) for s in (*modal.metrics, *tool.metrics)] == [
        ("Modal/G", MetricType.STRING), ("Tool/Number", MetricType.INT32)]
    assert [v for _, v in metric_values(modal, [ModalGCode(0, "G01"), ModalGCode(13, "G54")])] == [
        '{"0":"G01","13":"G54"}']
    assert [v for _, v in metric_values(tool, 12)] == [12]
    default = parse_config(WORK_OFFSET_CONFIG.replace("work_offsets: [54, 56]", "timers: true"), "t", {})
    names = {s.name for s in MachinePlan.build(poll_settings(default.machines[0].poll, default.alarms)).metrics()}
    assert not {"Modal/G", "Tool/Number"} & names


def test_library_only_flags_on_a_native_only_machine_warn_naming_them() -> None:
    flags = "work_offsets: [54], modal: true, tool_number: true"
    native_only = parse_config(WORK_OFFSET_CONFIG.replace("work_offsets: [54, 56]", flags), "t", {})
    [warning] = [w for w in native_only.warnings if "native transport alone" in w]
    assert "work_offsets, modal, tool_number" in warning and "fwlib_host" in warning
    routed = parse_config(WORK_OFFSET_CONFIG.replace("work_offsets: [54, 56]", flags).replace(
        "host: h\n", "host: h\n    fwlib_host: 'tcp:127.0.0.1:18193'\n"), "t", {})
    assert not [w for w in routed.warnings if "native transport alone" in w]
