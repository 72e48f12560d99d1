"""The OPC UA server: a feature of the application, on the gateway's own event loop (asyncua).

    start   the server's certificate (made on the first start), the endpoint with the security
            offered, the logins (`logins`), the address space (`address_space`), the writes
            and methods routed to the command path (`command_path`); then it listens
    serve   what the poller hands it goes into the variables (`shown`, one task): a client
            reads and subscribes to what the poller last read, never to the line
    stop    the server closes its sessions and its listener

Values are written only when they differ from what is shown (a Good value keeps the time it
was first read so); a drive that goes offline shows BadCommunicationError on each of its
variables, and Good values again from the first poll it answers.
"""

from __future__ import annotations

import asyncio
import datetime
import logging
from collections.abc import Sequence
from typing import Final

from asyncua import Node, Server, ua
from asyncua.common.callback import CallbackType

from gateway.bus import BusSettings
from gateway.errors import CannotListen
from gateway.mqtt.commands import CommandDrive, Commands
from gateway.opcua import client_faults
from gateway.opcua.address_space import (
    NAMESPACE,
    RUN_STATE,
    TAKES_FREQUENCY,
    AddressSpaceBuilder,
    DriveNodes,
    MethodCall,
)
from gateway.opcua.bounds import bound_monitored_items
from gateway.opcua.certificates import ClientTrust, ensure_server_certificate, thumbprint
from gateway.opcua.command_path import AuditedEvents, CommandPath, CommandWrites
from gateway.opcua.drive_events import DriveEvents
from gateway.opcua.logins import CALLER, ConsoleLogins, Login, Permissions
from gateway.opcua.parameters import ParameterNodes
from gateway.opcua.removal import Detached, detach_and_delete, reattach, tell_gone
from gateway.opcua.values import data_value, run_state, status_value
from gateway.poller import DriveEvent, Poller
from gateway.poller.drive_state import iso_time
from gateway.profile.telemetry import Telemetry
from gateway.routing import Router
from gateway.settings import DriveSettings, OpcUaSettings
from gateway.store import EventStore
from gateway.tasks import ServiceTasks, cancel_and_wait

log = logging.getLogger(__name__)

_POLICY = ua.SecurityPolicyType
POLICIES: Final = {
    "None": _POLICY.NoSecurity,
    "Basic256Sha256_Sign": _POLICY.Basic256Sha256_Sign,
    "Basic256Sha256_SignAndEncrypt": _POLICY.Basic256Sha256_SignAndEncrypt,
    "Aes128_Sha256_RsaOaep_Sign": _POLICY.Aes128Sha256RsaOaep_Sign,
    "Aes128_Sha256_RsaOaep_SignAndEncrypt": _POLICY.Aes128Sha256RsaOaep_SignAndEncrypt,
    "Aes256_Sha256_RsaPss_Sign": _POLICY.Aes256Sha256RsaPss_Sign,
    "Aes256_Sha256_RsaPss_SignAndEncrypt": _POLICY.Aes256Sha256RsaPss_SignAndEncrypt,
}
"""`opcua.security`'s words (OPC UA's policy names, then the mode) as asyncua has them."""
STOP_BUDGET_S: Final = 0.4
OFFLINE: Final = None
"""What `_pending` holds for a drive gone offline."""


class OpcUaServer:
    def __init__(
        self,
        settings: OpcUaSettings,
        buses: Sequence[BusSettings],
        drives: Sequence[DriveSettings],
        router: Router,
        poller: Poller,
        tasks: ServiceTasks,
        events: EventStore,
    ) -> None:
        self.settings = settings
        self.buses = buses
        self.drives = drives
        self.tasks = tasks
        self.router = router
        command_drives = {
            d.name: CommandDrive(d.name, router.route_for_drive(d.name), d.profile) for d in drives
        }
        self.command_drives = command_drives
        audited = AuditedEvents(events).as_store()
        commands = Commands(
            settings, router, poller, command_drives, audited, source="opcua", client="opcua"
        )
        self.path = CommandPath(commands, settings.commands_enabled)
        self.parameters = ParameterNodes(
            commands, settings.parameter_max_age_s, settings.parameters
        )
        self.poller = poller
        self.server: Server | None = None
        self.nodes: dict[str, DriveNodes] = {}
        self._pending: dict[str, Telemetry | None] = {}
        self._events: list[DriveEvent] = []
        self.drive_events: DriveEvents | None = None
        self._news = asyncio.Event()
        self._shower: asyncio.Task[None] | None = None
        self._builder: AddressSpaceBuilder | None = None
        self._gateway_node: Node | None = None
        self._bus_nodes: dict[str, Node] = {}

    # -- PollListener: called by the poller, return at once ----------------------------------

    def state_updated(self, drive: str, telemetry: Telemetry) -> None:
        if drive in self.nodes:
            self._pending[drive] = telemetry
            self._news.set()

    def availability_changed(self, drive: str, online: bool) -> None:
        if drive in self.nodes and not online:
            self._pending[drive] = OFFLINE
            self._news.set()

    def drive_event(self, event: DriveEvent) -> None:
        if event.drive in self.nodes:
            self._events.append(event)
            self._news.set()

    # -- lifecycle ---------------------------------------------------------------------------

    async def start(self) -> None:
        settings = self.settings
        client_faults.install()
        server = Server(user_manager=ConsoleLogins(settings.users, settings.anonymous))
        await server.init()
        server.iserver.max_connections = settings.max_connections
        server.iserver.max_subscriptions = settings.max_subscriptions
        bound_monitored_items(server.iserver.subscription_service, settings.max_monitored_items)
        server.set_endpoint(settings.endpoint)
        server.set_server_name(f"invt-gateway {settings.gateway_id}")
        await server.set_application_uri(settings.application_uri)
        await self._security(server)
        namespace = await server.register_namespace(NAMESPACE)
        builder = AddressSpaceBuilder(server, namespace, settings.commands_enabled)
        self.drive_events = DriveEvents(server, namespace)
        await self.drive_events.install()
        await self._address_space(builder, self.drive_events)
        iserver = server.iserver
        iserver.attribute_service = CommandWrites(
            iserver.aspace, builder.targets, self.path, self.parameters.written
        )
        self.parameters.server = server
        server.subscribe_server_callback(CallbackType.PreRead, self.parameters.before_read)
        try:
            await server.start()
        except OSError as exc:
            raise CannotListen(f"OPC UA server on {settings.host}:{settings.port}: {exc}") from exc
        self.server = server
        self._shower = self.tasks.start("opcua:values", self._show_forever())
        log.info("OPC UA server on %s (%s)", settings.endpoint, ", ".join(settings.security))

    async def _security(self, server: Server) -> None:
        settings = self.settings
        certificate = ensure_server_certificate(
            settings.certificate_file,
            settings.private_key_file,
            settings.application_uri,
            f"invt-gateway {settings.gateway_id}",
            settings.host,
        )
        await server.load_certificate(str(settings.certificate_file))
        await server.load_private_key(str(settings.private_key_file))
        log.info("OPC UA server certificate thumbprint (SHA-1): %s", thumbprint(certificate))
        if "None" in settings.security:
            log.warning(
                "OPC UA: security policy None is offered (opcua.security): no signing, no "
                "encryption, passwords in clear on the network"
            )
        server.set_security_policy(
            [POLICIES[name] for name in settings.security], permission_ruleset=Permissions()
        )
        tokens = [ua.UserNameIdentityToken]
        if settings.anonymous:
            tokens.append(ua.AnonymousIdentityToken)
        server.set_identity_tokens(tokens)
        trust = ClientTrust(settings.trusted_clients_dir, settings.rejected_clients_dir)
        server.set_certificate_validator(trust)

    async def _address_space(self, builder: AddressSpaceBuilder, events: DriveEvents) -> None:
        gateway = await builder.gateway(self.settings.gateway_id)
        await events.notifier(builder.server.nodes.server, gateway)
        self._builder, self._gateway_node = builder, gateway
        for bus in self.buses:
            bus_node = await builder.bus(gateway, bus.name)
            await events.notifier(gateway, bus_node)
            self._bus_nodes[bus.name] = bus_node
        for drive in self.drives:
            await self._add_drive(drive)
        self._news.set()

    async def _add_drive(self, drive: DriveSettings) -> None:
        """The drive's object under its bus, its values, methods and parameters; shown as the
        poller has it now."""
        builder, events = self._builder, self.drive_events
        bus_node = self._bus_nodes.get(drive.bus)
        if builder is None or events is None or self._gateway_node is None or bus_node is None:
            return
        command_drive = self.command_drives[drive.name]
        maximum = self.poller.max_frequency_hz.get(drive.name)
        nodes = await builder.drive(bus_node, drive, command_drive, self._method, maximum)
        drive_node = builder.server.get_node(builder.node_id(drive.name))
        writable = self.settings.commands_enabled
        targets = await self.parameters.add(builder.ns, drive_node, command_drive, writable)
        builder.targets.update(targets)
        await events.notifier(bus_node, drive_node)
        events.drive(drive.name, (drive_node.nodeid, bus_node.nodeid, self._gateway_node.nodeid))
        self.nodes[drive.name] = nodes
        if self.poller.availability(drive.name) is False:
            self._pending[drive.name] = OFFLINE
        elif telemetry := self.poller.telemetry(drive.name):
            self._pending[drive.name] = telemetry

    async def drives_changed(self, removed: Sequence[str], added: Sequence[DriveSettings]) -> None:
        """A reload: the removed drives' nodes deleted (their clients' items told
        BadNodeIdUnknown), the added ones' made; a changed drive (removed and added again) made
        anew with the same NodeIds, its clients' items moved onto them; every other node stays
        as it is, NodeIds, values and the clients' monitored items with them."""
        detached = {name: await self._remove_drive(name) for name in removed}
        for drive in added:
            self.command_drives[drive.name] = CommandDrive(
                drive.name, self.router.route_for_drive(drive.name), drive.profile
            )
            await self._add_drive(drive)
            # A changed drive (removed and added again): its clients' items go on with it.
            if self.server is not None and drive.name in detached:
                detached[drive.name] = reattach(self.server, detached[drive.name])
        for items in detached.values():
            await tell_gone(items)
        self._news.set()

    async def _remove_drive(self, name: str) -> Detached:
        self.nodes.pop(name, None)
        self._pending.pop(name, None)
        self.command_drives.pop(name, None)
        if self.drive_events is not None:
            self.drive_events.chains.pop(name, None)
        if self._builder is not None:
            for targets in (self._builder.targets, self.parameters.nodes):
                for node_id in [n for n, t in targets.items() if t.drive.name == name]:
                    del targets[node_id]
        if self.server is None or self._builder is None:
            return {}
        return await detach_and_delete(self.server, self._builder.node_id(name))

    def _method(self, drive: CommandDrive, command: str) -> MethodCall:
        async def call(parent: ua.NodeId, *arguments: ua.Variant) -> ua.CallMethodResult:
            payload: dict[str, object] = {"command": command}
            given = arguments[0].Value if arguments else None  # a Null argument: left out
            if given is not None and command in TAKES_FREQUENCY:  # checked as MQTT's
                payload["frequency_hz"] = given
            answer = await self.path.carry(drive, payload, CALLER.get())
            return ua.CallMethodResult(
                StatusCode=ua.StatusCode(answer.status),
                OutputArguments=[ua.Variant(answer.words, ua.VariantType.String)],
            )

        return call

    async def stop(self) -> None:
        if self._shower is not None:
            await cancel_and_wait(self._shower, STOP_BUDGET_S)
        server, self.server = self.server, None
        if server is None:
            return
        # asyncua's stop waits for its CurrentTime loop to wake from its 1 s sleep: longer than
        # a feature has to stop. The loop is ended here, and its stop finds nothing to wait for.
        clock = server.iserver.time_task
        server.iserver.time_task = None
        if clock is not None:
            await cancel_and_wait(clock, STOP_BUDGET_S)
        await asyncio.wait_for(server.stop(), STOP_BUDGET_S)

    def sessions(self) -> list[dict[str, str]]:
        """The logged-in sessions, for the console's diagnostics: user, role, since."""
        server = self.server
        if server is None:
            return []
        users = [session.user for session in list(server.iserver._external_sessions.values())]
        logins = sorted((u for u in users if isinstance(u, Login)), key=lambda u: u.since)
        return [
            {"user": u.shown, "role": u.console_role, "since": iso_time(u.since)} for u in logins
        ]

    # -- values ------------------------------------------------------------------------------

    async def _show_forever(self) -> None:
        while True:
            await self._news.wait()
            self._news.clear()
            pending, self._pending = self._pending, {}
            events, self._events = self._events, []
            for drive, telemetry in pending.items():
                nodes = self.nodes.get(drive)  # None: removed by a reload meanwhile
                if nodes is not None:
                    await self._show(nodes, telemetry)
            for event in events:
                if self.drive_events is not None:
                    await self.drive_events.trigger(event)

    async def _show(self, nodes: DriveNodes, telemetry: Telemetry | None) -> None:
        server = self.server
        if server is None:
            return
        now = datetime.datetime.now(datetime.UTC)
        if telemetry is not OFFLINE and "state" in telemetry and RUN_STATE not in telemetry:
            telemetry = {**telemetry, RUN_STATE: run_state(telemetry["state"])}
        for key, (node_id, kind) in nodes.variables.items():
            if telemetry is OFFLINE:
                value = status_value(ua.StatusCodes.BadCommunicationError, now)
            elif key in telemetry:
                value = data_value(kind, telemetry[key], now)
            else:
                continue
            shown = nodes.shown.get(key)
            if shown is not None and (shown.Value, shown.StatusCode) == (
                value.Value,
                value.StatusCode,
            ):
                continue
            nodes.shown[key] = value
            await server.write_attribute_value(node_id, value)
