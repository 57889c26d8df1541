"""Large responses encoded in slices are asyncua's bytes, and the loop gets turns while they are encoded."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest
from asyncua import ua
from asyncua.ua.ua_binary import struct_to_binary

from edge.opcua import turns
from edge.opcua.large_responses import encode_results


def _browse(count: int) -> ua.BrowseResponse:
    response = ua.BrowseResponse()
    response.ResponseHeader.RequestHandle = 17
    response.Results = [ua.BrowseResult(References=[ua.ReferenceDescription(
        ReferenceTypeId=ua.NodeId(ua.ObjectIds.Organizes), NodeId=ua.ExpandedNodeId(f"m{index}/Metrics/{ref}", 2),
        BrowseName=ua.QualifiedName(str(ref), 2), DisplayName=ua.LocalizedText(str(ref)),
        NodeClass=ua.NodeClass.Variable) for ref in range(index % 4)]) for index in range(count)]
    return response


def _read(count: int) -> ua.ReadResponse:
    response = ua.ReadResponse()
    response.Results = [ua.DataValue(ua.Variant(float(index))) for index in range(count)]
    response.DiagnosticInfos = [ua.DiagnosticInfo(SymbolicId=3)]
    return response


def _created(count: int) -> ua.CreateMonitoredItemsResponse:
    response = ua.CreateMonitoredItemsResponse()
    response.Results = [ua.MonitoredItemCreateResult(MonitoredItemId=index, RevisedSamplingInterval=20.0,
                                                     RevisedQueueSize=1) for index in range(count)]
    return response


def _created_unusual() -> ua.CreateMonitoredItemsResponse:
    """Results the struct pack leaves to asyncua (a filter result) or writes itself (none, a bad status)."""
    response = _created(4)
    response.Results[0].FilterResult = ua.EventFilterResult(SelectClauseResults=[ua.StatusCode()])
    response.Results[1].FilterResult = None
    response.Results[2].StatusCode = ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown)
    response.Results[3].FilterResult = ua.ExtensionObject(TypeId=ua.NodeId(5, 0), Body=b"x")
    return response


@pytest.mark.asyncio
@pytest.mark.parametrize("response", [_browse(0), _browse(3), _browse(700), _read(300), _created(1000),
                                      _created_unusual()],
                         ids=["empty", "few", "browse", "read", "created", "created-unusual"])
async def test_the_bytes_are_asyncuas(response: Any) -> None:
    assert await encode_results(response) == struct_to_binary(response)


@pytest.mark.asyncio
async def test_a_large_response_gives_the_loop_turns_while_it_is_encoded(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(turns, "SLICE_S", 0.0)  # a turn after every slice: the slices made are counted
    ran = 0

    async def other_work() -> None:
        nonlocal ran
        while True:
            ran += 1
            await asyncio.sleep(0)

    task = asyncio.create_task(other_work())
    await asyncio.sleep(0)
    before = ran
    response = _created(10 * turns.STEP)
    assert await encode_results(response) == struct_to_binary(response)
    task.cancel()
    assert ran - before >= 9  # the other task ran between the 10 slices
