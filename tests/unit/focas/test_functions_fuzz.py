"""Fuzz: every FOCAS response decoder (native subpacket payloads and write extras) on arbitrary bytes.

Frames and the packed surface have their own property tests (test_frame_properties.py,
packed/test_properties.py); these cover each function's payload layout, which is where a control of an
unexpected series (or a broken one) sends bytes nobody planned for. Only ProtocolError (or a CncError a
payload itself reports) may come out. `make fuzz` runs these with the long hypothesis profile.
"""

from __future__ import annotations

import contextlib

from hypothesis import given
from hypothesis import strategies as st

from edge.focas import frame as fr
from edge.focas import function_entry as fe
from edge.focas import functions as fn
from edge.focas.errors import CncError, ProtocolError

contexts = st.builds(fe.Context, max_axis=st.integers(1, 32), slot_form=st.sampled_from(list(fn.SlotForm)))
int16 = st.integers(-(2**15), 2**15 - 1)
args = st.tuples(int16, int16, int16, int16)


@given(st.sampled_from(fn.FUNCTIONS), args, st.binary(max_size=300), contexts)
def test_fuzz_every_payload_decoder_raises_only_protocol_errors(function: fe.Function,
                                                                arguments: tuple[int, int, int, int],
                                                                payload: bytes, ctx: fe.Context) -> None:
    req = function.request(*arguments)
    with contextlib.suppress(ProtocolError, CncError):
        function.decode_payload(payload, req, ctx)


@given(st.sampled_from([f for f in fn.FUNCTIONS if f.is_write]), args, st.binary(max_size=300), contexts)
def test_fuzz_write_extras_decode_or_raise_protocol_errors(function: fe.Function,
                                                           arguments: tuple[int, int, int, int],
                                                           extra: bytes, ctx: fe.Context) -> None:
    assert function.decode_extra is not None
    req = function.request(*arguments, extra=extra)
    with contextlib.suppress(ProtocolError, CncError):
        function.decode_extra(req, ctx)


@given(st.binary(max_size=600))
def test_fuzz_response_and_request_bodies_raise_only_protocol_errors(body: bytes) -> None:
    with contextlib.suppress(ProtocolError):
        fr.decode_response_body(body)
    with contextlib.suppress(ProtocolError):
        fr.decode_request_body(body)


@given(st.lists(st.binary(max_size=80), max_size=30))
def test_fuzz_stream_decoder_consumes_any_chunks_without_hanging(chunks: list[bytes]) -> None:
    decoder = fr.FrameDecoder()
    fed = 0
    for chunk in chunks:
        data = fr.encode_open_response() + chunk
        fed += len(data)
        try:
            decoder.feed(data)
        except ProtocolError:
            break
    assert decoder.buffered <= fed  # it never holds more than it was given
