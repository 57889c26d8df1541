"""The machines in the server's address space: built at each birth, updated in place per sample.

A machine's birth (its metric specs and first values) adds its object, the 40501 components, the
`Metrics` folder and one variable per metric (plus its 40501 mirror, edge.opcua.layout), in one batch
through the node management service. A sample then becomes the value of the metric's node(s) and is told
to the attribute's monitored items (edge.opcua.subscriptions), which is what asyncua's own
write_attribute_value does, without its per-call type check: the value was built for the node's type
(edge.opcua.values).

Most values are never read: without a client, or with one subscribed to some metrics only, each changed
value would build a DataValue (a Variant, a datetime, the encoded bytes: ~5 us and two objects for the
collector to sweep) to be replaced unseen a poll later. So a metric's slot keeps the latest sample and the
server time it arrived at, and its nodes' Value attribute reads the slot (asyncua's value_callback): the
DataValue is built when a monitored item is told of the change, or when a client reads it, once.
"""

from __future__ import annotations

import logging
import struct
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from asyncua import ua
from asyncua.server.internal_server import InternalServer

from edge.opcua import layout, nodes
from edge.opcua.encoding import MAX_MS, MIN_MS, TICKS_PER_MS, WIN_EPOCH_OFFSET_MS
from edge.opcua.shared_attributes import SharedAttributes
from edge.opcua.subscriptions import (
    CHANGES,
    GatewayMonitoredItems,
    Tap,
    enqueue,
    link,
    queue_more,
    taps_of,
    unlink,
)
from edge.opcua.values import (
    KINDS,
    NULL_TYPE,
    QUALITY_STATUS,
    WIN_EPOCH_US,
    LazyDataValue,
    SharedDataValue,
    data_value,
    offline_value,
    server_now,
    server_time,
    status_code,
    variant_type,
)
from edge.samples import MetricSpec, MetricType, Sample

log = logging.getLogger(__name__)

_WAITING = "BadWaitingForInitialData"

Pending = tuple[int, Any, SharedDataValue]  # (handle, asyncua data-change callback, value) to await
_NO_PENDING: list[Pending] = []  # shared, never appended to: `_pending` copies it first
_NO_TAPS: list[Tap] = []
_NO_OTHERS: list[tuple[int, Any]] = []


def _pending(slow: list[Pending], others: Any, value: SharedDataValue) -> list[Pending]:
    if slow is _NO_PENDING:
        slow = []
    slow.extend((handle, callback, value) for handle, callback in others)
    return slow


async def deliver(slow: list[Pending]) -> None:
    """Hand changes to the monitored items on asyncua's own path (items with a filter), in order."""
    for handle, callback, value in slow:
        await callback(handle, value)


@dataclass(slots=True)
class MetricSlot:
    """Where one metric's value lives, for the Value attribute of each node showing it: `shown`, or when
    that is None, built from the latest `sample` and the `server_ns` it arrived at on the first read."""

    kind: MetricType
    node_ids: list[ua.NodeId]
    attributes: list[Any]  # asyncua AttributeValue (value_callback + datachange_callbacks)
    writable: bool = False
    shown: SharedDataValue | None = None
    sample: Sample | None = None
    server_ns: int = 0
    # who a change reaches, made from the attributes' data-change callbacks at subscriptions.CHANGES[0] ==
    # `changes` (`retap`): the taps of the usual client items, the other callbacks, whether there is any
    changes: int = -1
    taps: list[Tap] = field(default_factory=lambda: _NO_TAPS)
    others: list[tuple[int, Any]] = field(default_factory=lambda: _NO_OTHERS)
    watched: bool = False
    # what a client sees of the value shown (raw value, variant type, status code), for the StatusValue
    # trigger without a DataValue; code -1: not known (a change nobody watched), `reading` finds it
    raw: object = None
    vtype: Any = None
    code: int = -1

    def read(self, _node_id: object = None, _attribute_id: object = None) -> SharedDataValue:
        """The DataValue the nodes show (asyncua's value_callback: Read, a new monitored item's first value)."""
        shown = self.shown
        if shown is None:
            assert self.sample is not None  # shown is only cleared with a sample stored
            shown = self.shown = data_value(self.sample, server_time(self.server_ns))
        return shown

    def reading(self) -> tuple[object, Any, int]:
        """(raw value, variant type, status code) of the value shown; a code of -1 when none compares equal."""
        if self.code >= 0:
            return self.raw, self.vtype, self.code
        if self.shown is None and self.sample is None:
            return None, None, -1
        shown = self.read()
        if type(shown) is LazyDataValue:
            return shown.raw, shown.vtype, shown.StatusCode.value
        return None, None, -1  # (the waiting or offline value: no sample's value equals it)

    def retap(self, changes: int) -> None:
        for tap in self.taps:
            unlink(tap[0])
        taps: list[Tap] = []
        others: list[tuple[int, Any]] = []
        for attribute in self.attributes:
            if attribute.datachange_callbacks:
                more_taps, more_others = taps_of(attribute.datachange_callbacks)
                taps += more_taps
                others += more_others
        for tap in taps:
            link(tap[0], self)
        self.taps = taps or _NO_TAPS
        self.others = others or _NO_OTHERS
        self.watched = bool(taps or others)
        self.changes = changes


def _retap_all(machine: MachineNodes, changes: int) -> bool:
    """Make the taps of every slot of the machine not made at `changes` (before any takes a sample of the
    batch: an unlinked item keeps the value it saw); whether no slot is watched."""
    quiet = True
    for slot in machine.slots.values():
        if slot.changes != changes:
            slot.retap(changes)
        if slot.watched:
            quiet = False
    return quiet


@dataclass
class MachineNodes:
    device_id: str
    object_id: ua.NodeId
    notifier_id: ua.NodeId
    slots: dict[str, MetricSlot] = field(default_factory=dict)
    paths: set[str] = field(default_factory=set)  # paths below the machine object that have a node
    online: bool = False
    # no slot of the machine reaches a monitored item (every slot's taps made at CHANGES[0] == `checked_at`):
    # `show` then only stores each sample (the server with no client, or a client watching other machines)
    quiet: bool = False
    checked_at: int = -1


class GatewaySpace:
    """Every machine's nodes below Objects/Machines, in the gateway's namespace."""

    def __init__(self, iserver: InternalServer, namespace: int) -> None:
        self.iserver = iserver
        self.ns = namespace
        self.machines: dict[str, MachineNodes] = {}
        self.folder = ua.NodeId(layout.MACHINES_FOLDER, namespace)
        # metric node -> (machine, metric): a client's write of any of them goes to the command layer,
        # which decides (and audits) also for the read-only ones
        self.by_node: dict[ua.NodeId, tuple[str, str]] = {}
        self.values_set = 0
        self.attributes = SharedAttributes()

    def setup(self) -> None:
        objects = ua.NodeId(ua.ObjectIds.ObjectsFolder)
        self._add([nodes.folder(self.folder, layout.MACHINES_FOLDER, objects)])

    # ---- births ------------------------------------------------------------------------------------
    def machine_online(self, device_id: str, specs: Sequence[MetricSpec], samples: Iterable[Sample],
                       writable: Callable[[MetricSpec], bool]) -> MachineNodes:
        """Create (or extend) the machine's nodes for `specs` and show `samples`; metrics no longer in the
        birth are removed."""
        machine = self.machines.get(device_id)
        if machine is None:
            machine = self._create_machine(device_id)
        wanted = {spec.name: spec for spec in specs}
        self._remove(machine, [name for name in machine.slots if name not in wanted])
        items: list[ua.AddNodesItem] = []
        waiting = SharedDataValue(ua.Variant(None), StatusCode=status_code(_WAITING), ServerTimestamp=server_now().when)
        for name in sorted(wanted):
            spec = wanted[name]
            may_write = writable(spec)
            slot = machine.slots.get(name)
            if slot is None:
                slot = self._create_metric(machine, spec, may_write, items)
                if slot is not None:
                    machine.slots[name] = slot
            elif slot.writable != may_write:
                slot.writable = may_write
                self._set_access(slot, may_write)
        self._add(items)
        for name, slot in machine.slots.items():
            if not slot.attributes:  # new: no value until a sample brings one
                slot.attributes = [self._value_attribute(node_id) for node_id in slot.node_ids]
                slot.shown = waiting
                for attribute in slot.attributes:
                    attribute.value = None
                    attribute.value_callback = slot.read
            for node_id in slot.node_ids:
                self.by_node[node_id] = (device_id, name)
        machine.online = True
        machine.checked_at = -1  # new slots: `show` looks again whether the machine is quiet
        return machine

    def _create_machine(self, device_id: str) -> MachineNodes:
        ns = self.ns
        object_id = ua.NodeId(device_id, ns)
        notifier = ua.NodeId(f"{device_id}/{layout.MESSAGES}", ns)
        machine = MachineNodes(device_id, object_id, notifier)
        items = [nodes.component(object_id, device_id, self.folder, notifier=True)]
        items[0].ReferenceTypeId = ua.NodeId(ua.ObjectIds.Organizes)
        for name in layout.COMPONENTS:
            items.append(nodes.component(self._id(device_id, name), name, object_id))
            machine.paths.add(name)
        items.append(nodes.component(notifier, "Messages", self._id(device_id, "Notification"), notifier=True))
        machine.paths.add(layout.MESSAGES)
        items.append(nodes.folder(self._id(device_id, layout.METRICS_FOLDER), layout.METRICS_FOLDER, object_id))
        machine.paths.add(layout.METRICS_FOLDER)
        manufacturer = ua.Variant(layout.MANUFACTURER, ua.VariantType.String)
        items.append(nodes.variable(self._id(device_id, "Identification/Manufacturer"), "Manufacturer",
                                    self._id(device_id, "Identification"), ua.VariantType.String, manufacturer))
        self._add(items)
        self.machines[device_id] = machine
        return machine

    def _create_metric(self, machine: MachineNodes, spec: MetricSpec, writable: bool,
                       items: list[ua.AddNodesItem]) -> MetricSlot | None:
        vtype = variant_type(spec.type)
        node_ids = []
        for path, folder in ((layout.metric_path(spec.name), True), (layout.mirror_path(spec.name), False)):
            if path is None:
                continue
            if path in machine.paths:
                log.warning("metric not shown in OPC UA: its node path is taken machine=%s metric=%s path=%s",
                            machine.device_id, spec.name, path)
                continue
            parent = self._parents(machine, path, folder, items)
            node_id = self._id(machine.device_id, path)
            items.append(nodes.variable(node_id, path.rsplit("/", 1)[-1], parent, vtype, ua.Variant(),
                                        writable=writable, description=spec.description, has_unit=bool(spec.unit)))
            if spec.unit:
                items.append(nodes.engineering_units(self._id(machine.device_id, f"{path}#EngineeringUnits"),
                                                     node_id, spec.unit))
            machine.paths.add(path)
            node_ids.append(node_id)
        if not node_ids:
            return None
        return MetricSlot(spec.type, node_ids, [], writable)

    def _parents(self, machine: MachineNodes, path: str, folder: bool, items: list[ua.AddNodesItem]) -> ua.NodeId:
        """The node id of the parent of `path`, adding the folders (Metrics) or objects (40501) on the way."""
        parts = path.split("/")
        for depth in range(1, len(parts)):
            prefix = "/".join(parts[:depth])
            if prefix not in machine.paths:
                parent = self._id(machine.device_id, "/".join(parts[:depth - 1]))
                make = nodes.folder if folder else nodes.component
                items.append(make(self._id(machine.device_id, prefix), parts[depth - 1], parent))
                machine.paths.add(prefix)
        return self._id(machine.device_id, "/".join(parts[:-1]))

    def _remove(self, machine: MachineNodes, names: list[str]) -> None:
        if not names:
            return
        params = ua.DeleteNodesParameters()
        for name in names:
            slot = machine.slots.pop(name)
            for node_id in slot.node_ids:
                self.by_node.pop(node_id, None)
                params.NodesToDelete.append(ua.DeleteNodesItem(NodeId=node_id, DeleteTargetReferences=True))
                machine.paths.discard(str(node_id.Identifier).split("/", 1)[1])
        self.iserver.node_mgt_service.delete_nodes(params)
        machine.checked_at = -1
        log.info("metrics removed from OPC UA machine=%s count=%d", machine.device_id, len(names))

    # ---- values ------------------------------------------------------------------------------------
    def show(self, device_id: str, samples: Iterable[Sample]) -> list[Pending]:
        """Show the samples' values and tell the gateway's monitored items, synchronously; returns the
        monitored items that need asyncua's coroutine (a filter), to be awaited in order (`deliver`).

        A client's usual item is told through its tap (subscriptions.taps_of): the change is queued as the
        notification's bytes, with `notify`'s checks made when the taps were. The StatusValue trigger (no
        notification when neither value nor status changed) is checked once per value, against the value the
        metric showed: every tapped item has been told each value since it was created or enabled (when its
        own first value was this slot's), so that is the value each of them last saw.

        A monitored change builds no DataValue: the usual value (of the node's Python type, Good or Uncertain)
        is encoded here, compared by (raw value, variant type, status code) kept in the slot, and its
        DataValue built from the sample only when read (a Read, an item not on a tap). A tapped item's
        current value is the slot's (subscriptions.TappedValues), not stored per change."""
        machine = self.machines.get(device_id)
        if machine is None:
            return _NO_PENDING
        slots = machine.slots
        now_ns = time.time_ns()
        server_ticks = (now_ns // 1000 + WIN_EPOCH_US) * 10  # the ServerTimestamp, as server_time(now_ns) has it
        changes = CHANGES[0]
        count = 0
        if machine.checked_at != changes:  # every slot's taps made again here, not per value in the loop
            machine.quiet = _retap_all(machine, changes)
            machine.checked_at = changes
        if machine.quiet:  # nobody watches any of its values: each is only stored, built when read
            for sample in samples:
                slot = slots.get(sample.name)
                if slot is not None and not sample.historical:
                    slot.sample = sample
                    slot.server_ns = now_ns
                    slot.shown = None
                    slot.code = -1
                    count += 1
            self.values_set += count
            return _NO_PENDING
        slow = _NO_PENDING
        kinds, qualities = KINDS, QUALITY_STATUS
        for sample in samples:
            slot = slots.get(sample.name)
            if slot is None or sample.historical:
                continue
            count += 1
            if not slot.watched:
                slot.sample = sample
                slot.server_ns = now_ns
                slot.shown = None  # built from the sample when read
                slot.code = -1
                continue
            # data_value's encoding, inline for the usual value (of the node's Python type, Good or Uncertain)
            _status, bad, code = qualities[sample.quality]
            native, _convert, vtype, encode = kinds[sample.type]
            raw = sample.value
            stamp = sample.timestamp_ms
            encoded = None
            if not bad and type(raw) is native and MIN_MS < stamp < MAX_MS:
                try:
                    encoded = encode(raw, code, (stamp + WIN_EPOCH_OFFSET_MS) * TICKS_PER_MS, server_ticks)
                except (struct.error, OverflowError):  # outside the node's type: data_value's BadTypeMismatch
                    encoded = None
            built = None
            if encoded is None:  # any other: data_value's own way (conversion, null, BadTypeMismatch)
                built = data_value(sample, server_time(now_ns))
                raw, vtype, code, encoded = built.raw, built.vtype, built.StatusCode.value, built.encoded
            before = slot.code
            if before < 0:
                before_raw, before_vtype, before = slot.reading()
            else:
                before_raw, before_vtype = slot.raw, slot.vtype
            slot.sample = sample
            slot.server_ns = now_ns
            slot.shown = built  # None: built from the sample when read
            slot.raw = raw
            slot.vtype = vtype
            slot.code = code
            if before != code or before_vtype is not vtype or before_raw != raw:  # asyncua's StatusValue trigger
                for _values, mid, prefix, bound, subscription in slot.taps:  # GatewayMonitoredItems.notify's work
                    queue = subscription._triggered_datachanges
                    pending = queue.get(mid)
                    if pending is None:
                        queue[mid] = prefix + encoded  # bare (subscriptions.enqueue)
                    else:
                        queue_more(queue, mid, pending, prefix + encoded, bound)
            if slot.others:
                value = slot.read()
                for handle, callback in slot.others:
                    owner = getattr(callback, "__self__", None)
                    if type(owner) is not GatewayMonitoredItems or not owner.notify(handle, value):
                        slow = _pending(slow, ((handle, callback),), value)
        self.values_set += count
        return slow

    def show_offline(self, device_id: str) -> list[Pending]:
        """The machine's CNC session is down: every value Bad (BadNoCommunication), no value."""
        machine = self.machines.get(device_id)
        if machine is None:
            return _NO_PENDING
        machine.online = False
        value = offline_value(server_now())
        code = value.StatusCode.value
        changes = CHANGES[0]
        slow = _NO_PENDING
        for slot in machine.slots.values():
            if slot.changes != changes:
                slot.retap(changes)
            before_raw, before_vtype, before = slot.reading()
            slot.shown = value
            slot.sample = None
            slot.raw, slot.vtype, slot.code = None, NULL_TYPE, code
            if before != code or before_vtype is not NULL_TYPE or before_raw is not None:
                for _values, mid, prefix, bound, subscription in slot.taps:
                    enqueue(subscription._triggered_datachanges, mid, prefix + value.encoded, bound)
            for handle, callback in slot.others:
                owner = getattr(callback, "__self__", None)
                if type(owner) is not GatewayMonitoredItems or not owner.notify(handle, value):
                    slow = _pending(slow, ((handle, callback),), value)
        return slow

    async def update(self, device_id: str, samples: Iterable[Sample]) -> None:
        """Show the samples' values and tell every monitored item."""
        await deliver(self.show(device_id, samples))

    async def offline(self, device_id: str) -> None:
        await deliver(self.show_offline(device_id))

    def metric_of(self, node_id: ua.NodeId) -> tuple[str, str] | None:
        """(machine, metric) shown by a node, else None."""
        return self.by_node.get(node_id)

    def slot(self, device_id: str, metric: str) -> MetricSlot | None:
        machine = self.machines.get(device_id)
        return machine.slots.get(metric) if machine is not None else None

    # ---- helpers -----------------------------------------------------------------------------------
    def _id(self, device_id: str, path: str) -> ua.NodeId:
        return ua.NodeId(f"{device_id}/{path}" if path else device_id, self.ns)

    def _add(self, items: list[ua.AddNodesItem]) -> None:
        if not items:
            return
        added = []
        for item, result in zip(items, self.iserver.node_mgt_service.add_nodes(items), strict=True):
            if result.StatusCode.is_good():
                added.append(self.iserver.aspace[result.AddedNodeId])
            else:
                log.warning("OPC UA node not added node=%s status=%s", item.RequestedNewNodeId, result.StatusCode)
        self.attributes.share(added)

    def _value_attribute(self, node_id: ua.NodeId) -> Any:
        return self.iserver.aspace[node_id].attributes[ua.AttributeIds.Value]

    def _set_access(self, slot: MetricSlot, writable: bool) -> None:
        level = ua.DataValue(ua.Variant(nodes.READ_WRITE if writable else nodes.READ, ua.VariantType.Byte))
        for node_id in slot.node_ids:
            node = self.iserver.aspace[node_id]
            node.attributes[ua.AttributeIds.AccessLevel].value = level
            node.attributes[ua.AttributeIds.UserAccessLevel].value = level

