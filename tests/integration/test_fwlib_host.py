"""The FOCAS library host over real Unix sockets, with the stand-in library (tests/fwlib/standin.c) behind it.

PackedClient -> packed endpoint -> worker thread -> ctypes -> the stand-in's C structs and in-memory state.
"""

from __future__ import annotations

import asyncio
import ctypes
import os
import stat
import struct
import subprocess
import sys
import time
from collections.abc import AsyncIterator
from datetime import UTC, datetime
from pathlib import Path

import pytest

from edge.focas import items as it
from edge.focas import packed as pk
from edge.focas.errors import AccessDenied, Busy, CncError, FunctionNotAvailable, OutOfRange
from edge.focas.model import ModalGCode
from edge.focas.packed.client import PackedClient
from edge.focas.packed.frame import FrameDecoder, PackedFrame
from edge.fwlib import calls
from edge.fwlib import structs as st
from edge.fwlib.host import FwlibHost, start_host
from edge.fwlib.library import load_library
from edge.fwlib.settings import HostSettings
from edge.fwlib.worker import EW_SOCKET, EW_UNEXP
from tests.fwlib.standin import Standin, standin_library
from tests.helpers import async_wait_for

pytestmark = pytest.mark.integration

BIT, BYTE, WORD, TWO_WORD, REAL = range(5)
PMC_R = 5  # fwlib32.h's adr_type for R


@pytest.fixture
def standin() -> Standin:
    return Standin(standin_library())


def settings_for(tmp_path: Path, names: list[str], call_timeout_s: float = 5.0) -> HostSettings:
    return HostSettings.model_validate({
        "library": standin_library(),
        "log_file": str(tmp_path / "focas.log"),
        "call_timeout_s": call_timeout_s,
        "connect_timeout_s": 2,
        "backoff_initial_s": 0.05,
        "backoff_max_s": 0.2,
        "socket_mode": 0o600,
        "machines": [{"name": n, "cnc": f"10.0.0.{i + 1}:8193", "listen": f"unix:{tmp_path}/{n}.sock",
                      "params": {6711: "two_word", 1815: "bit", 20: "byte", 1420: "word", 1320: "real"},
                      "diag": {300: "two_word"}} for i, n in enumerate(names)],
    })


@pytest.fixture
async def host(standin: Standin, tmp_path: Path) -> AsyncIterator[FwlibHost]:
    running = await start_host(settings_for(tmp_path, ["mill-1", "mill-2"], call_timeout_s=2.0),
                               load_library(standin_library()))
    try:
        for worker in running.workers.values():
            await asyncio.wait_for(worker.wait_available(), 10)
        yield running
    finally:
        standin.release()  # a hung call in the stand-in returns, so its thread ends
        await running.close()


@pytest.fixture
async def cnc(host: FwlibHost) -> AsyncIterator[PackedClient]:
    client = PackedClient(host.endpoints["mill-1"].address, timeout=5.0, connect_timeout=5.0)
    await client.connect()
    try:
        yield client
    finally:
        await client.close()


async def raw_call(host: FwlibHost, command: int, payload: bytes) -> bytes:
    reader, writer = await asyncio.open_unix_connection(host.endpoints["mill-1"].unix_path)
    try:
        writer.write(PackedFrame(command, 7, payload).encode())
        await writer.drain()
        decoder = FrameDecoder()
        while not (frames := decoder.feed(await asyncio.wait_for(reader.read(65536), 5.0))):
            pass
        return frames[0].payload
    finally:
        writer.close()
        await writer.wait_closed()


# ---- start-up and identity ------------------------------------------------------------------------------
async def test_library_process_started_and_sysinfo_read_through_the_struct(
        standin: Standin, cnc: PackedClient) -> None:
    assert standin.started_up() == 1
    info = await cnc.read_sysinfo()
    assert (info.cnc_type, info.mt_type, info.series, info.version, info.max_axis) == ("31", " M", "G421",
                                                                                        "0013", 32)
    status = await cnc.read_status()
    assert (status.aut, status.run, status.motion) == (1, 3, 1)


async def test_unix_socket_is_only_for_its_owner(host: FwlibHost) -> None:
    mode = stat.S_IMODE(os.stat(host.endpoints["mill-1"].unix_path).st_mode)
    assert mode == 0o600


# ---- alarm history ---------------------------------------------------------------------------------------
async def test_empty_history_is_an_empty_list(cnc: PackedClient) -> None:
    assert await cnc.read_alarm_history(250) == []


async def test_one_entry_carries_the_cnc_time_and_fields(standin: Standin, cnc: PackedClient) -> None:
    standin.push_alarm((2026, 11, 23, 14, 5, 9), 1001, b"SPINDLE OVERHEAT", axis=2, group=4)
    [entry] = await cnc.read_alarm_history(10)
    assert entry.occurred == datetime(2026, 11, 23, 14, 5, 9, tzinfo=UTC)
    assert (entry.alm_no, entry.alm_type, entry.axis_no, entry.message) == (1001, 4, 2, "SPINDLE OVERHEAT")


async def test_250_entries_come_back_newest_first_in_chunks_of_ten(standin: Standin, cnc: PackedClient) -> None:
    for n in range(250):
        standin.push_alarm((2026, 1, 1 + n // 24, n % 24, n % 60, 0), n, f"ALARM {n}".encode())
    entries = await cnc.read_alarm_history(250)
    assert [e.alm_no for e in entries] == list(range(249, -1, -1))
    assert entries[0].message == "ALARM 249"
    assert [e.alm_no for e in await cnc.read_alarm_history(15)] == list(range(249, 234, -1))


@pytest.mark.parametrize("length", range(0, 33))
async def test_messages_of_0_to_32_bytes(standin: Standin, cnc: PackedClient, length: int) -> None:
    text = bytes(ord("A") + i % 26 for i in range(length))
    standin.push_alarm((2026, 2, 3, 4, 5, 6), 500, text)
    [entry] = await cnc.read_alarm_history(1)
    assert entry.message == text.decode()


async def test_a_len_msg_past_the_buffer_is_clamped_and_a_negative_one_is_empty(
        standin: Standin, cnc: PackedClient) -> None:
    standin.push_alarm((2026, 2, 3, 4, 5, 6), 1, b"B" * 64, length=-7)
    standin.push_alarm((2026, 2, 3, 4, 5, 7), 2, b"C" * 64, length=200)
    newest, oldest = await cnc.read_alarm_history(2)
    assert newest.message == "C" * 64  # ODBAHIS4 holds 64 bytes
    assert oldest.message == ""


async def test_bad_dates_skip_that_entry_only(standin: Standin, cnc: PackedClient) -> None:
    standin.push_alarm((2026, 3, 1, 8, 0, 0), 1, b"GOOD OLD")
    standin.push_alarm((2026, 13, 1, 8, 0, 0), 2, b"MONTH 13")
    standin.push_alarm((2026, 2, 30, 8, 0, 0), 3, b"FEB 30")
    standin.push_alarm((0, 0, 0, 0, 0, 0), 4, b"ZEROS")
    standin.push_alarm((2026, 3, 2, 8, 0, 0), 5, b"GOOD NEW")
    assert [e.alm_no for e in await cnc.read_alarm_history(10)] == [5, 1]


async def test_a_negative_depth_is_clamped_to_one(standin: Standin, host: FwlibHost) -> None:
    standin.push_alarm((2026, 3, 1, 8, 0, 0), 1, b"ONE")
    standin.push_alarm((2026, 3, 1, 8, 0, 1), 2, b"TWO")
    payload = await raw_call(host, pk.Command.RDALMHISTRY, struct.pack("<h", -5))
    assert [e.alm_no for e in pk.decode_alarm_history(payload)] == [2]


@pytest.mark.parametrize(("version", "kept"), [(4, 64), (3, 32), (2, 32)])
async def test_the_newest_history_call_the_control_has_is_chosen(
        standin: Standin, cnc: PackedClient, version: int, kept: int) -> None:
    standin.set_history_version(version)
    standin.push_alarm((2026, 3, 1, 8, 0, 0), 7, b"M" * 64)
    [entry] = await cnc.read_alarm_history(1)
    assert entry.message == "M" * kept


async def test_a_control_without_history_is_the_seeds_empty_list_and_the_clients_ew_func(
        standin: Standin, host: FwlibHost, cnc: PackedClient) -> None:
    standin.set_history_version(0)
    standin.push_alarm((2026, 3, 1, 8, 0, 0), 7, b"X")
    payload = await raw_call(host, pk.Command.RDALMHISTRY, struct.pack("<h", 10))
    assert struct.unpack("<h", payload) == (-1,)  # num_alm = -EW_FUNC
    assert pk.decode_alarm_history(payload) == []  # the seed's codec rule
    with pytest.raises(FunctionNotAvailable):  # the client says why: the poller drops it, listed as such
        await cnc.read_alarm_history(10)


@pytest.mark.parametrize(("code", "kind"), [(-1, Busy), (-16, CncError), (5, CncError), (3, OutOfRange)])
async def test_a_history_call_the_library_refuses_is_that_error_at_the_client_not_an_empty_list(
        standin: Standin, host: FwlibHost, cnc: PackedClient, code: int, kind: type[CncError]) -> None:
    standin.set_history_version(3)
    standin.push_alarm((2026, 3, 1, 8, 0, 0), 7, b"X")
    standin.fail_history(code, 1)
    with pytest.raises(kind) as caught:
        await cnc.read_alarm_history(10)
    assert caught.value.code == code  # library-side (negative) codes too: -1 is EW_BUSY, not EW_FUNC
    await asyncio.wait_for(host.workers["mill-1"].wait_available(), 10)  # EW_SOCKET: the handle is reopened
    assert [e.alm_no for e in await cnc.read_alarm_history(10)] == [7]  # and the next call answers


# ---- parameters, macros, PMC -----------------------------------------------------------------------------
@pytest.mark.parametrize(("number", "ptype", "start", "value"), [
    (1815, BIT, 0, 0b10100101),
    (20, BYTE, 4, -7),
    (1420, WORD, 1000, -12345),
    (6711, TWO_WORD, 0, 2_000_000_000),
    (1320, REAL, 0, 123.456),
])
async def test_parameter_writes_of_every_width_read_back(
        standin: Standin, cnc: PackedClient, number: int, ptype: int, start: int, value: int | float) -> None:
    standin.set_param(number, ptype, start)
    before = await cnc.write_param(number, value)
    assert before.values == (start,)
    [read] = await cnc.read_params(number)
    assert read.values == (value,) and read.type == ptype
    if ptype == REAL:
        assert standin.param(number) == 123456  # prm_val, with dec_val 3
    else:
        assert standin.param(number) == value


async def test_a_parameter_without_a_configured_type_is_refused_not_guessed(
        standin: Standin, cnc: PackedClient) -> None:
    standin.set_param(4000, TWO_WORD, 5)
    with pytest.raises(OutOfRange):
        await cnc.read_params(4000)


async def test_locked_parameter_write_is_access_denied_and_changes_nothing(
        standin: Standin, cnc: PackedClient) -> None:
    standin.set_param(6711, TWO_WORD, 10)
    standin.set_pwe(0)
    with pytest.raises(AccessDenied):
        await cnc.write_param(6711, 99)
    assert standin.param(6711) == 10


async def test_locked_write_travels_as_the_surfaces_11(standin: Standin, host: FwlibHost) -> None:
    standin.set_param(6711, TWO_WORD, 10)
    standin.set_pwe(0)
    payload = await raw_call(host, pk.Command.WRPARAM, pk.encode_param_write(6711, 0, TWO_WORD, 5))
    assert struct.unpack("<h", payload) == (pk.PACKED_EW_PASSWD,)


async def test_diagnosis_reads_use_the_diag_table(standin: Standin, cnc: PackedClient) -> None:
    standin.set_param(300, TWO_WORD, 4242)
    [record] = await cnc.read_diag(300)
    assert record.values == (4242,)


async def test_macro_round_trip_and_vacant(cnc: PackedClient) -> None:
    assert await cnc.read_macros(501) == [None]
    await cnc.write_macro(500, 12.345)
    assert await cnc.read_macros(500) == [12.345]


async def test_pmc_range_of_70_bytes_is_three_library_calls(standin: Standin, cnc: PackedClient) -> None:
    data = bytes(range(1, 71))
    await cnc.write_pmc("R", 1000, data)
    assert standin.calls("pmc_wrpmcrng") == 3
    assert (standin.last_wrpmc_start(), standin.last_wrpmc_end()) == (1064, 1069)
    assert bytes(standin.pmc(PMC_R, 1000 + i) for i in range(70)) == data
    assert await cnc.read_pmc("R", 1000, 1069) == list(data)


async def test_pmc_read_of_words_and_a_33_byte_raw_write(standin: Standin, host: FwlibHost,
                                                         cnc: PackedClient) -> None:
    for i, b in enumerate(struct.pack("<hh", -2, 300)):
        standin.set_pmc(PMC_R, 10 + i, b)
    assert await cnc.read_pmc("R", 10, 13, 1) == [-2, 300]
    payload = await raw_call(host, pk.Command.WRPMCRNG, struct.pack("<hhHH", 5, 0, 0, 32) + bytes(33))
    assert struct.unpack("<h", payload) == (2,)  # EW_LENGTH before any library call


# ---- a hung call, a lost handle ---------------------------------------------------------------------------
async def test_a_hung_call_marks_only_that_cnc_unavailable(standin: Standin, host: FwlibHost) -> None:
    standin.hang_macro(9999)
    async with (PackedClient(host.endpoints["mill-1"].address, timeout=10.0) as hung,
                PackedClient(host.endpoints["mill-2"].address, timeout=10.0) as other):
        started = time.monotonic()
        stuck = asyncio.create_task(hung.read_macros(9999))
        await async_wait_for(lambda: host.endpoints["mill-1"].requests_for(pk.Command.RDMACRO), timeout=5)
        await other.write_macro(100, 7.0)  # the other CNC's thread is free while mill-1's is blocked
        assert await other.read_macros(100) == [7.0]
        assert not stuck.done()
        with pytest.raises(CncError) as caught:
            await stuck
        assert caught.value.code == EW_SOCKET
        assert time.monotonic() - started < 8  # the 2 s call timeout, not the stand-in's 60 s hang
        await asyncio.wait_for(host.workers["mill-1"].wait_available(), 10)
        assert host.workers["mill-1"].connects == 2  # a fresh handle on a fresh thread, the old one still hung
        assert await hung.read_macros(100) == [7.0]


async def test_a_history_call_that_hangs_rests_while_the_other_reads_of_its_cnc_go_on(
        standin: Standin, host: FwlibHost, cnc: PackedClient) -> None:
    """Issue 24's stand-in: cnc_rdalmhistry3 hangs on every call. It is bounded by the call timeout (2 s
    here), answers EW_SOCKET, and then rests (hung_rest_s, 60 s by default): answered at once without a
    library call, so the CNC's other reads are not held up by it again and no second thread is abandoned."""
    standin.set_history_version(3)
    standin.push_alarm((2026, 3, 1, 8, 0, 0), 7, b"X")
    await cnc.write_macro(100, 3.0)
    standin.hang_history(-1)
    started = time.monotonic()
    with pytest.raises(CncError) as caught:
        await cnc.read_alarm_history(10)
    assert caught.value.code == EW_SOCKET
    assert time.monotonic() - started < 5  # the 2 s call timeout, not the stand-in's 60 s hang
    worker = host.workers["mill-1"]
    await asyncio.wait_for(worker.wait_available(), 10)
    assert await cnc.read_macros(100) == [3.0]
    calls, connects = standin.calls("cnc_rdalmhistry"), worker.connects
    started = time.monotonic()
    results = await cnc.batch([it.ReadAlarmHistory(10), it.ReadMacros(100, 100), it.ReadAlarmHistory(10)])
    assert time.monotonic() - started < 1.0  # no call timeout waited for
    assert [getattr(r, "code", r) for r in results] == [EW_SOCKET, [3.0], EW_SOCKET]
    assert (standin.calls("cnc_rdalmhistry"), worker.connects) == (calls, connects)  # the library was not asked


async def test_a_lost_handle_is_reopened(standin: Standin, host: FwlibHost, cnc: PackedClient) -> None:
    await cnc.write_macro(100, 1.0)
    standin.drop_handles()
    with pytest.raises(CncError):
        await cnc.read_macros(100)  # EW_HANDLE (-8) from the library
    await asyncio.wait_for(host.workers["mill-1"].wait_available(), 10)
    assert await cnc.read_macros(100) == [1.0]


async def test_refused_connects_are_retried_with_backoff(standin: Standin, tmp_path: Path) -> None:
    standin.refuse_connects(3)
    running = await start_host(settings_for(tmp_path, ["mill-9"]), load_library(standin_library()))
    try:
        await asyncio.wait_for(running.workers["mill-9"].wait_available(), 10)
        assert standin.calls("cnc_allclibhndl3") == 4
    finally:
        await running.close()


# ---- the command ------------------------------------------------------------------------------------------
def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "edge", "fwlib-host", *args], capture_output=True, text=True,
                          timeout=60)


def write_config(tmp_path: Path, library: str) -> Path:
    config = tmp_path / "fwlib-host.yaml"
    config.write_text(f"library: {library}\nmachines:\n  - name: m1\n    cnc: 10.0.0.1\n"
                      f"    listen: unix:{tmp_path}/m1.sock\n")
    return config


def test_a_library_of_another_architecture_exits_2_naming_path_and_both_architectures(tmp_path: Path) -> None:
    fake = tmp_path / "libfwlib32.so"
    header = b"\x7fELF" + bytes([1, 1, 1]) + bytes(9) + struct.pack("<HHI", 3, 40, 1)  # ET_DYN, EM_ARM
    fake.write_bytes(header + bytes(64))
    result = run_cli("--config", str(write_config(tmp_path, str(fake))))
    assert result.returncode == 2
    assert str(fake) in result.stderr
    assert "ARM (32-bit)" in result.stderr and "-bit Python" in result.stderr


def test_a_missing_library_exits_2_naming_the_path(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere" / "libfwlib32.so"
    result = run_cli("--config", str(write_config(tmp_path, str(missing))))
    assert result.returncode == 2
    assert str(missing) in result.stderr and "no such file" in result.stderr


def test_a_non_loopback_tcp_listen_is_refused_without_allow_remote(tmp_path: Path) -> None:
    config = tmp_path / "fwlib-host.yaml"
    config.write_text("library: /x.so\nmachines:\n  - {name: m1, cnc: 10.0.0.1, listen: 'tcp:0.0.0.0:18193'}\n")
    result = run_cli("--config", str(config))
    assert result.returncode == 2 and "not loopback" in result.stderr


def test_the_command_serves_until_sigterm_and_exits_0(standin: Standin, tmp_path: Path) -> None:
    config = tmp_path / "fwlib-host.yaml"
    config.write_text(f"library: {standin_library()}\nlog_file: {tmp_path}/focas.log\nsocket_mode: 0o600\n"
                      f"machines:\n  - {{name: m1, cnc: 10.0.0.1, listen: 'unix:{tmp_path}/m1.sock'}}\n")
    proc = subprocess.Popen([sys.executable, "-m", "edge", "fwlib-host", "--config", str(config)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        lines = [proc.stdout.readline(), proc.stdout.readline()]
        assert lines[0].startswith("m1") and f"unix:{tmp_path}/m1.sock" in lines[0]
        assert lines[1].startswith("ready")

        async def read_sysinfo() -> str:
            async with PackedClient(f"unix:{tmp_path}/m1.sock", timeout=5.0, connect_timeout=5.0) as cnc:
                return (await cnc.read_sysinfo()).series

        async def when_open() -> str:
            deadline = time.monotonic() + 10
            while True:  # the handle opens in the background: sysinfo answers EW_SOCKET until then
                try:
                    return await read_sysinfo()
                except CncError:
                    if time.monotonic() > deadline:
                        raise
                    await asyncio.sleep(0.05)

        assert asyncio.run(when_open()) == "G421"
        proc.terminate()
        assert proc.wait(timeout=20) == 0
        assert not (tmp_path / "m1.sock").exists()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


# ---- work-coordinate offsets (cnc_rdzofs, packed ext 0x400D) ----------------------------------------------
async def test_work_offset_travels_as_least_increments_and_arrives_in_mm(standin: Standin,
                                                                           cnc: PackedClient) -> None:
    standin.set_work_offset(1, 1, -123456)
    standin.set_work_offset(1, 2, 1)
    standin.set_work_offset(2, 1, 5000)
    assert await cnc.read(it.ReadWorkOffsets(1)) == [-123.456, 0.001, 0.0]
    assert await cnc.read(it.ReadWorkOffsets(2)) == [5.0, 0.0, 0.0]
    # every axis (type -1): the length covers the header and the stand-in's three controlled axes
    assert standin.last_rdzofs_length() == st.IODBZOFS.data.offset + 3 * ctypes.sizeof(ctypes.c_long)


async def test_a_work_offset_the_control_lacks_is_its_error_not_a_value(cnc: PackedClient) -> None:
    with pytest.raises(OutOfRange, match="cnc_rdzofs"):
        await cnc.read(it.ReadWorkOffsets(42))


# ---- modal G codes (cnc_rdgcode, ext 0x400E) and the T code in use (cnc_modal, ext 0x400F) ---------------
async def test_modal_g_codes_of_the_active_block_come_through_the_library(cnc: PackedClient) -> None:
    assert await cnc.read(it.ReadModalGCodes()) == [
        ModalGCode(0, "G01"), ModalGCode(1, "G17"), ModalGCode(2, "G90"), ModalGCode(13, "G54")]


async def test_tool_number_in_use_is_cnc_modals_t_code(standin: Standin, cnc: PackedClient) -> None:
    standin.set_tool(12)
    assert await cnc.read(it.ReadToolNumber()) == 12
    standin.set_tool(7)
    assert await cnc.read(it.ReadToolNumber()) == 7


# ---- a programming error in a translation -----------------------------------------------------------------
async def test_a_translation_that_raises_answers_an_error_and_the_cnc_keeps_serving(
        monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture, host: FwlibHost,
        cnc: PackedClient) -> None:
    def broken(library_cnc: object, payload: bytes) -> bytes:
        raise ZeroDivisionError("a slip in the translation")

    monkeypatch.setitem(calls.TRANSLATIONS, pk.Command.RDMACRO, broken)
    with pytest.raises(CncError) as caught:
        await cnc.read_macros(100)
    assert caught.value.code == EW_UNEXP
    assert "ZeroDivisionError" in caplog.text and "mill-1" in caplog.text
    assert host.workers["mill-1"].connects == 1 and host.workers["mill-1"].available  # the handle is kept
    await cnc.write_macro(100, 3.0)  # same connection, same handle: the next requests are served
    monkeypatch.undo()
    assert await cnc.read_macros(100) == [3.0]
