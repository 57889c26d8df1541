"""CNC alarms as OPC UA events: active alarms as AlarmConditionType, history entries as events once.

The collector already turns the CNC's alarm list into raise/clear events (`Alarm/Event`) and its alarm
history ring into entries published once (`Alarm/History`; a watermark in state_dir keeps a restart
from publishing them again). Both reach the server as the same samples the MQTT publisher gets, so the
server re-fires nothing on its own.

- `Alarm/Event` raised/cleared -> an AlarmConditionType event, ConditionId `<machine>/Alarms/<type>.<number>.<axis>`,
  Time = the CNC time of the tick that saw it, ActiveState true/false, Retain while active (so
  ConditionRefresh replays the active ones). The CNC clears its alarms itself: the conditions need no
  Acknowledge/Confirm and are sent AckedState/ConfirmedState true.
- `Alarm/History` entries -> a `CncAlarmHistoryEventType` event (BaseEventType + AlarmType, AlarmNumber,
  Axis), Time = the occurrence time the CNC recorded.

Each event is emitted from the Server object (where alarm clients subscribe, and where ConditionRefresh
works) and again from the machine's Notification/Messages object.
"""

from __future__ import annotations

import json
import logging
import uuid
from collections.abc import Iterable
from datetime import UTC, datetime

from asyncua import ua
from asyncua.common import event_objects
from asyncua.common.events import Event
from asyncua.server.internal_server import InternalServer

from edge.samples import Sample, utc_datetime

log = logging.getLogger(__name__)

ALARM_EVENT = "Alarm/Event"
ALARM_HISTORY = "Alarm/History"
HISTORY_EVENT_TYPE = "CncAlarmHistoryEventType"
HISTORY_FIELDS = (("AlarmType", ua.VariantType.Int32), ("AlarmNumber", ua.VariantType.Int32),
                  ("Axis", ua.VariantType.Int32))
ALARM_SEVERITY = 700
HISTORY_SEVERITY = 500
_SERVER = ua.NodeId(ua.ObjectIds.Server)


class AlarmEvents:
    """Builds and triggers the events of every machine's alarm samples."""

    def __init__(self, iserver: InternalServer, history_type: ua.NodeId, namespace: int) -> None:
        self.iserver = iserver
        self.history_type = history_type
        self.namespace = namespace
        self.emitted = 0

    async def emit(self, device_id: str, machine: ua.NodeId, notifier: ua.NodeId, samples: Iterable[Sample]) -> None:
        for sample in samples:
            if sample.name not in (ALARM_EVENT, ALARM_HISTORY):
                continue
            try:
                body = json.loads(str(sample.value))
                if not isinstance(body, dict):
                    raise ValueError("not an object")
                events = (self._condition(device_id, machine, body, sample.timestamp_ms)
                          if sample.name == ALARM_EVENT else self._history(device_id, machine, body, sample))
            except (ValueError, TypeError, KeyError) as exc:
                log.warning("alarm sample not turned into an event machine=%s metric=%s error=%s", device_id,
                            sample.name, exc)
                continue
            await self._trigger(events, notifier)

    def _condition(self, device_id: str, machine: ua.NodeId, body: dict[str, object], when_ms: int) -> Event:
        active = body["event"] == "raised"
        alarm_type, number, axis = int(body["type"]), int(body["number"]), int(body.get("axis") or 0)  # type: ignore[call-overload]
        event = event_objects.AlarmCondition(sourcenode=machine, message=str(body.get("message") or ""),
                                             severity=ALARM_SEVERITY)
        # ConditionId (the select clause on ConditionType with an empty browse path reads "NodeId")
        event.add_property("NodeId", ua.NodeId(f"{device_id}/Alarms/{alarm_type}.{number}.{axis}", self.namespace),
                           ua.VariantType.NodeId)
        self._stamp(event, device_id, when_ms)
        event.ConditionName = f"{alarm_type}.{number}" + (f".{axis}" if axis else "")
        event.Retain = active
        event.EnabledState = ua.LocalizedText("Enabled")
        _set(event, "EnabledState/Id", True)
        event.ActiveState = ua.LocalizedText("Active" if active else "Inactive")
        _set(event, "ActiveState/Id", active)
        event.add_property("ActiveState/TransitionTime", utc_datetime(when_ms), ua.VariantType.DateTime)  # UtcTime
        event.AckedState = ua.LocalizedText("Acknowledged")
        _set(event, "AckedState/Id", True)
        event.ConfirmedState = ua.LocalizedText("Confirmed")
        _set(event, "ConfirmedState/Id", True)
        return event

    def _history(self, device_id: str, machine: ua.NodeId, body: dict[str, object], sample: Sample) -> Event:
        event = event_objects.BaseEvent(sourcenode=machine, message=str(body.get("message") or ""),
                                        severity=HISTORY_SEVERITY)
        event.EventType = self.history_type
        event.add_property("AlarmType", int(body["type"]), ua.VariantType.Int32)  # type: ignore[call-overload]
        event.add_property("AlarmNumber", int(body["number"]), ua.VariantType.Int32)  # type: ignore[call-overload]
        event.add_property("Axis", int(body.get("axis") or 0), ua.VariantType.Int32)  # type: ignore[call-overload]
        self._stamp(event, device_id, int(body.get("occurred_ms", sample.timestamp_ms)))  # type: ignore[call-overload]
        return event

    @staticmethod
    def _stamp(event: Event, device_id: str, when_ms: int) -> None:
        event.EventId = uuid.uuid4().bytes
        event.SourceName = device_id
        event.Time = utc_datetime(when_ms)
        event.ReceiveTime = datetime.now(UTC)

    async def _trigger(self, event: Event, notifier: ua.NodeId) -> None:
        """From the Server object (recorded as a condition while Retain is true, for ConditionRefresh), then
        a copy from the machine's notifier, sent to its subscribers only."""
        event.emitting_node = _SERVER
        service = self.iserver.subscription_service
        await service.trigger_event(event)
        local = _copy(event)
        local.emitting_node = notifier
        for subscription in list(service.subscriptions.values()):
            await subscription.monitored_item_srv.trigger_event(local)
        self.emitted += 1


def _set(event: Event, name: str, value: object) -> None:
    setattr(event, name, value)


def _copy(event: Event) -> Event:
    clone = object.__new__(type(event))
    clone.__dict__.update(event.__dict__)
    return clone
