"""The asyncua server of the gateway: endpoint, security, the machines' address space, writes to metrics.

Runs on whichever event loop starts it (edge.opcua.output decides: its own thread, or the daemon's
loop). A client's Write of a metric node does not change the node: it goes to the `WriteHandler` (the
command layer, on the daemon's loop) and the client gets the StatusCode of the outcome; the new value
arrives like any other, from the collector's read-back.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable, Coroutine, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asyncua import Server, ua
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.address_space import AttributeService

from edge.opcua import alarms, layout, processor, subscriptions, views
from edge.opcua.address_space import GatewaySpace, Pending
from edge.opcua.security import PasswordUsers, ensure_certificate
from edge.opcua.settings import SECURITY_MODES, OpcUaSettings
from edge.opcua.values import client_value, status_code
from edge.opcua.writes import WriteOutcome, status_for
from edge.samples import MetricSpec, Sample

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class MetricWrite:
    """A client's write of one metric node, as the server hands it to the command layer."""

    device_id: str
    metric: str
    value: object
    client: str  # the OPC UA user name ("anonymous" when allowed and used)
    node: str  # the node id written, for the audit line
    refusal: tuple[str, str] | None = None  # (reply code, reason) when the server already refused it


MetricWriter = Callable[[MetricWrite], Coroutine[Any, Any, WriteOutcome]]


class GatewayServer:
    """One OPC UA endpoint serving every machine's metrics and alarm events."""

    def __init__(self, settings: OpcUaSettings, writer: MetricWriter | None = None) -> None:
        self.settings = settings
        self.writer = writer
        self.users = PasswordUsers(settings.users, settings.allow_anonymous)
        self.server: Server | None = None
        self.space: GatewaySpace | None = None
        self.alarms: alarms.AlarmEvents | None = None
        # machine_data without awaiting: what is left for asyncua's own monitored items (`deliver` it). The
        # address space's `show` itself once started (the output calls it for every batch: no call between)
        self.show_data: Callable[[str, Sequence[Sample]], list[Pending]] = self._not_started

    async def start(self) -> None:
        settings = self.settings
        server = Server(user_manager=self.users)
        server.iserver.bind_condition_methods = 100  # ConditionRefresh (its Refresh events' severity)
        await server.init()
        server.set_endpoint(settings.endpoint)
        server.set_server_name(settings.server_name)
        server.product_uri = "urn:focas-edge"
        server.manufacturer_name = "focas-edge"
        await server.set_application_uri(settings.application_uri)
        server.set_security_policy([getattr(ua.SecurityPolicyType, SECURITY_MODES[mode])
                                    for mode in settings.security])
        tokens: list[type] = [ua.UserNameIdentityToken]
        if settings.allow_anonymous:
            tokens.insert(0, ua.AnonymousIdentityToken)
        server.set_identity_tokens(tokens)
        if settings.encrypted:
            await self._load_certificate(server)
        iserver = server.iserver
        iserver.max_connections = settings.max_sessions
        iserver.max_subscriptions = 10 * settings.max_sessions
        iserver.max_monitored_item_queue_size = 100
        namespace = await server.register_namespace(settings.namespace_uri)
        history_type = await server.create_custom_event_type(
            namespace, alarms.HISTORY_EVENT_TYPE, ua.ObjectIds.BaseEventType, list(alarms.HISTORY_FIELDS))
        subscriptions.install(iserver.subscription_service)
        views.install(iserver)  # a browse of the whole tree: no walk of the reference types per reference
        processor.install()  # Publish dispatched first; large result lists encoded with the loop given turns
        space = GatewaySpace(iserver, namespace)
        space.setup()
        iserver.attribute_service = _GatewayAttributes(iserver.aspace, space, self._write)
        self.alarms = alarms.AlarmEvents(iserver, history_type.nodeid, namespace)
        self.space = space
        self.show_data = space.show
        await server.start()
        self.server = server
        log.info("OPC UA server listening endpoint=%s security=%s anonymous=%s users=%d", settings.endpoint,
                 ",".join(settings.security), settings.allow_anonymous, len(settings.users))

    async def stop(self) -> None:
        server, self.server = self.server, None
        if server is not None:
            await server.stop()
            log.info("OPC UA server stopped")

    async def _load_certificate(self, server: Server) -> None:
        settings = self.settings
        if settings.certificate_file is not None and settings.private_key_file is not None:
            certificate, key = settings.certificate_file, settings.private_key_file
        else:
            files = ensure_certificate(Path(settings.state_dir) / "opcua", settings.application_uri)
            certificate, key = files.certificate, files.private_key
        await server.load_certificate(str(certificate))
        await server.load_private_key(str(key))

    # ---- what the output hands over (on this server's loop) ----------------------------------------
    async def machine_online(self, device_id: str, specs: Sequence[MetricSpec], samples: Sequence[Sample],
                             writable: frozenset[str]) -> None:
        assert self.space is not None
        self.space.machine_online(device_id, specs, samples, lambda spec: spec.name in writable)
        await self.space.update(device_id, samples)

    async def machine_data(self, device_id: str, samples: Sequence[Sample]) -> None:
        assert self.space is not None
        await self.space.update(device_id, samples)

    @staticmethod
    def _not_started(device_id: str, samples: Sequence[Sample]) -> list[Pending]:
        raise RuntimeError("the OPC UA server is not started")

    async def machine_events(self, device_id: str, samples: Sequence[Sample]) -> None:
        assert self.space is not None and self.alarms is not None
        await self.space.update(device_id, samples)
        machine = self.space.machines.get(device_id)
        if machine is not None:
            await self.alarms.emit(device_id, machine.object_id, machine.notifier_id, samples)

    async def machine_offline(self, device_id: str) -> None:
        assert self.space is not None
        await self.space.offline(device_id)

    # ---- writes ------------------------------------------------------------------------------------
    async def _write(self, device_id: str, metric: str, variant: ua.Variant, user: User,
                     node: ua.NodeId) -> ua.StatusCode:
        assert self.space is not None
        slot = self.space.slot(device_id, metric)
        if slot is None or self.writer is None:
            return status_code("BadNotWritable")
        fits, value = client_value(variant, slot.kind)
        refusal = None
        if not fits:
            got = variant.VariantType.name if variant is not None else "nothing"
            expected = layout.VARIANT_TYPES[slot.kind]
            refusal = ("wrong_type", f"node {node.to_string()} holds {expected}; the client wrote {got}")
            value = variant.Value if variant is not None else None
        request = MetricWrite(device_id, metric, value, user.name or "anonymous", node.to_string(), refusal)
        try:
            outcome = await self.writer(request)
        except Exception:
            log.exception("OPC UA write failed in the command layer machine=%s metric=%s", device_id, metric)
            return status_code("BadInternalError")
        return status_code(status_for(outcome))


class _GatewayAttributes(AttributeService):
    """asyncua's attribute service with writes of metric nodes sent to the command layer."""

    def __init__(self, aspace: object, space: GatewaySpace,
                 write: Callable[[str, str, ua.Variant, User, ua.NodeId], Awaitable[ua.StatusCode]]) -> None:
        super().__init__(aspace)
        self._space = space
        self._write_metric = write

    async def write(self, params: ua.WriteParameters, user: User = User(role=UserRole.Admin)) -> list[ua.StatusCode]:  # noqa: B008
        results: list[ua.StatusCode] = []
        for item in params.NodesToWrite:
            target = self._space.metric_of(item.NodeId)
            if target is not None and item.AttributeId == ua.AttributeIds.Value:
                if item.IndexRange:
                    results.append(status_code("BadWriteNotSupported"))
                    continue
                value = item.Value.Value if item.Value is not None else None
                results.append(await self._write_metric(target[0], target[1], value, user, item.NodeId))
            elif item.NodeId.NamespaceIndex == self._space.ns and user.role != UserRole.Admin:
                results.append(status_code("BadNotWritable"))
            else:
                one = ua.WriteParameters()
                one.NodesToWrite = [item]
                results.extend(await super().write(one, user))
        return results
