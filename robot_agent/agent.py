"""The agent: wires settings, simulated world, motors, sensors, commands and the MQTT link on one loop.

Safety: motors stop when the broker link drops, on e-stop, when a drive's duration ends, and on shutdown.
Shutdown (SIGTERM/SIGINT) stops sensors and motors, publishes the retained offline status, disconnects and
joins the paho thread.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import signal
import time
import uuid
from typing import TYPE_CHECKING, Any

import orjson

import robot_agent.motion.commands  # noqa: F401 - registers drive, goto, follow_path
from fleet_protocol import (
    MOTION_COMMANDS,
    PROTOCOL_VERSION,
    QOS_HEARTBEAT,
    QOS_POSES,
    QOS_SITE,
    Ack,
    AgentConfig,
    Capabilities,
    Status,
    Topics,
    dumps,
    now,
)
from robot_agent import __version__
from robot_agent.commands import CommandHandler
from robot_agent.config import AgentSettings, ConfigError, parse_broker_url, sensor_configs
from robot_agent.debug_hooks import DebugOptions
from robot_agent.legacy.udp import LegacyUdpHub
from robot_agent.link.clock_sync import ClockSync
from robot_agent.link.watchdog import LinkWatchdog
from robot_agent.motion.collision_guard import GuardedMotors
from robot_agent.motion.kinematics import Kinematics
from robot_agent.motion.neighbours import NeighbourTable
from robot_agent.motion.runner import MotionRunner
from robot_agent.motors import create_motor_driver, validate_motor_config
from robot_agent.motors.watchdog import WATCHDOG_MARGIN_S
from robot_agent.sensors import SENSOR_REGISTRY
from robot_agent.sensors.base import SensorContext
from robot_agent.sensors.supervisor import SensorSupervisor, build_plugins
from robot_agent.sim.disturbances import Disturbance
from robot_agent.sim.world import Pose, SimWorld, start_pose_for
from robot_agent.telemetry.publisher import TelemetryPublisher
from robot_agent.telemetry.repair import RepairResponder
from robot_agent.telemetry.replay import ReplayDisk, ReplayRing

if TYPE_CHECKING:
    from robot_agent.link.mqtt import MqttTransport

log = logging.getLogger(__name__)

STATUS_REFRESH_S = 15.0


class Agent:
    def __init__(
        self, settings: AgentSettings, broker_url: str | None = None, debug: DebugOptions | None = None
    ) -> None:
        self.settings = settings
        self.robot_id = settings.robot_id
        self.broker_url = broker_url or settings.broker
        if self.broker_url is None:
            raise ConfigError("no broker: give --broker or use discovery")
        self.host, self.port = parse_broker_url(self.broker_url)
        if settings.tls_ca is not None and not settings.tls_ca.is_file():
            raise ConfigError(f"tls_ca {settings.tls_ca} is not a readable file")
        self.topics = Topics(settings.prefix)
        self.world: SimWorld | None = None
        if settings.simulate:
            sp = settings.start_pose_tuple()
            start = Pose(*sp) if sp else start_pose_for(self.robot_id)
            self.world = SimWorld(
                start=start,
                max_speed_mps=settings.max_speed_mps,
                wheel_base_m=settings.wheel_base_m,
                disturbance=Disturbance(settings.sim, self.robot_id),
            )
        self.shared: dict[str, Any] = {}
        self.legacy = LegacyUdpHub(settings.legacy_udp)
        self.shared["legacy_udp"] = self.legacy
        #: this run of the agent: telemetry carries it, because seq starts again at 0 after a restart
        self.boot = uuid.uuid4().hex[:16]
        disk = None
        if settings.replay_dir is not None:
            try:
                disk = ReplayDisk(settings.replay_dir, self.boot, settings.replay_max_bytes)
            except OSError as exc:
                raise ConfigError(f"replay_dir {settings.replay_dir}: {exc}") from None
        self.replay = ReplayRing(
            self.boot, window_s=settings.replay_window_s, max_bytes=settings.replay_max_bytes, disk=disk
        )
        self.repair = RepairResponder(ring=self.replay, publish=self._send_repair_reply)
        self.telemetry = TelemetryPublisher(
            self.topics, self.robot_id, self._send_telemetry, boot=self.boot, on_published=self.replay.add
        )
        self.plugins = build_plugins(sensor_configs(settings), SENSOR_REGISTRY, self._make_ctx)
        self.supervisor = SensorSupervisor(
            self.plugins, self._on_health_change, backoff_max_s=settings.sensor_retry_max_s
        )
        # Motors last: everything above only validates, so a config error never leaves pins claimed.
        motors = create_motor_driver(dict(settings.motors), self.world)
        self.shared["motors"] = motors  # the health sensor's motor_fault and simulated battery
        kinematics = Kinematics.from_config(settings.kinematics, settings.wheel_base_m, settings.max_speed_mps)
        skew = debug.clock_skew_s if debug else 0.0
        self.clock = ClockSync(
            self._send_time_request,
            on_first_sync=self._publish_status,
            wall=(lambda: time.time() + skew) if skew else time.time,
        )
        self.shared["clock"] = self.clock  # the health sensor's clock_offset_ms
        # every motion passes the safety filter: robots never collide (docs/safety.md)
        self.motors = GuardedMotors(
            motors,
            kinematics=kinematics,
            neighbours=NeighbourTable(self.robot_id),
            emit=self.telemetry.emit,
            server_time=lambda: self.clock.sender_now() if self.clock.synced else None,
        )
        self.shared["collision_guard"] = self.motors  # the health sensor's hears_poses
        self.motion = MotionRunner(
            kinematics=kinematics,
            motors=self.motors,
            send_ack=self._send_ack,
            emit=self.telemetry.emit,
            end_drive=lambda reason: self.commands.stop_all(reason),
            driving=lambda: self.commands.driving,
        )
        self.commands = CommandHandler(
            self.motors,
            self._send_ack,
            [*settings.extra_commands, *MOTION_COMMANDS],
            on_state_change=self._publish_status,
            clock=self.clock.sender_now,
            watchdog_margin_s=WATCHDOG_MARGIN_S if debug is None or debug.motor_watchdog else None,
            motion=self.motion,
        )
        self.watchdog = LinkWatchdog(
            lambda: self.commands.driving or self.motion.active, self._send_ping, self.commands.stop_all
        )
        self._retained: dict[str, dict[str, Any]] = {}
        self._link_ups = 0
        self._transport: MqttTransport | None = None  # made by run(): paho is imported only then
        self._tasks: list[asyncio.Task[None]] = []

    # -- status ----------------------------------------------------------------------------------------
    def capabilities(self) -> Capabilities:
        return Capabilities(sensors=self.supervisor.names, commands=self.commands.command_names)

    def status(self, online: bool) -> Status:
        return Status(
            clock_synced=self.clock.synced,
            clock_offset_ms=self.clock.offset_ms(),
            clock_rtt_ms=self.clock.rtt_ms(),
            online=online,
            ts=now(),
            agent_version=__version__,
            protocol_version=PROTOCOL_VERSION,
            capabilities=self.capabilities(),
            estop=self.commands.estop_engaged,
            sensors=self.supervisor.states(),
            buffer_dropped=self._transport.stats.buffer_dropped if self._transport else 0,
            keepalive_s=self.settings.keepalive,
            collision_filter=True,
        )

    def status_payload(self, online: bool = True, reason: str = "") -> bytes:
        body = self.status(online).model_dump(mode="json")
        if reason:
            body["reason"] = reason
        return orjson.dumps(body)

    def effective_config(self) -> dict[str, Any]:
        """What this agent runs with: settings merged from file, environment and flags, the broker it
        found, and every sensor and the motors with their defaults filled in. Secrets are removed by the
        payload model (fleet_protocol.redact)."""
        cfg = self.settings.model_dump(mode="json")
        cfg["broker"] = self.broker_url
        cfg["sensors"] = [p.config.model_dump(mode="json") for p in self.plugins]
        default_motor = "sim" if self.world is not None else "none"
        cfg["motors"] = validate_motor_config(dict(self.settings.motors), default_motor).model_dump(mode="json")
        return cfg

    def config_payload(self) -> bytes:
        msg = AgentConfig(
            ts=now(),
            agent_version=__version__,
            protocol_version=PROTOCOL_VERSION,
            boot=self.boot,
            config=self.effective_config(),
        )
        return dumps(msg)

    def _publish_status(self) -> None:
        if self._transport is not None:
            self._transport.publish_status()

    def _on_health_change(self) -> None:
        self._publish_status()

    async def _status_refresher(self) -> None:
        """Refresh the retained status now and then (sensor rates, buffer drops), and sooner when nothing
        else went out for half a keepalive: the server takes 1.5 x keepalive of silence as a dead link."""
        quiet_s = self.settings.keepalive / 2
        last_refresh = time.monotonic()
        while True:
            await asyncio.sleep(min(quiet_s / 2, STATUS_REFRESH_S))
            now = time.monotonic()
            transport = self._transport
            quiet = transport is not None and now - transport.last_publish >= quiet_s
            if quiet or now - last_refresh >= STATUS_REFRESH_S:
                last_refresh = now
                self._publish_status()

    # -- plugin hooks --------------------------------------------------------------------------------------
    def _make_ctx(self) -> SensorContext:
        return SensorContext(
            robot_id=self.robot_id,
            emit=self._emit,
            emit_retained=self._emit_retained,
            emit_camera=self._emit_camera,
            world=self.world,
            shared=self.shared,
        )

    def _emit(self, stream: str, data: dict[str, Any]) -> None:
        self.supervisor.count_emit(stream)
        self.telemetry.emit(stream, data)
        if stream == "position":
            self.motion.on_fix(data)  # the goal controllers run at the position sensor's rate

    def _emit_retained(self, stream: str, data: dict[str, Any]) -> None:
        self._retained[stream] = data
        self.telemetry.emit(stream, data, retain=True)

    def _emit_camera(self, stream: str, payload: bytes) -> None:
        self.supervisor.count_emit(stream)
        if self._transport is not None:
            self._transport.publish_camera(self.topics.camera(self.robot_id), payload)

    def _send_telemetry(self, topic: str, payload: bytes, retain: bool) -> None:
        if self._transport is not None:
            self._transport.publish_telemetry(topic, payload, retain)

    def _send_repair_reply(self, payload: bytes) -> None:
        if self._transport is not None:
            self._transport.publish_repair_reply(payload)

    def _send_ping(self, payload: bytes) -> None:
        if self._transport is not None:
            self._transport.publish_ping(payload)

    def _send_time_request(self, payload: bytes) -> None:
        if self._transport is not None:
            self._transport.publish_time_request(payload)

    def _send_ack(self, ack: Ack) -> None:
        if self._transport is not None:
            self._transport.publish_ack(dumps(ack))

    def _on_link(self, up: bool) -> None:
        if not up:
            self.commands.stop_all("link lost")
            log.warning("broker link lost: motors stopped")
            return
        self._link_ups += 1
        self.clock.sync_now()
        if self._link_ups == 1:
            return  # first connect: the retained messages are still in the offline buffer
        # A restarted broker forgot retained telemetry (e.g. the Lighthouse geometry): publish it again.
        for stream, data in self._retained.items():
            self.telemetry.emit(stream, data, retain=True)

    # -- run ---------------------------------------------------------------------------------------------
    async def run(self, stop: asyncio.Event) -> None:
        from robot_agent.link.mqtt import MqttTransport  # paho is imported when the agent runs, not before

        loop = asyncio.get_running_loop()
        self._transport = MqttTransport(
            loop=loop,
            topics=self.topics,
            robot_id=self.robot_id,
            host=self.host,
            port=self.port,
            keepalive=self.settings.keepalive,
            will_payload=self.status_payload(online=False, reason="connection lost"),
            status_payload=self.status_payload,
            config_payload=self.config_payload(),
            on_command=self.commands.handle_payload,
            on_estop=self.commands.handle_estop_payload,
            on_link=self._on_link,
            on_ping=self.watchdog.on_echo,
            on_time=self.clock.on_response,
            on_repair=self.repair.handle_payload,
            subscriptions={
                self.topics.heartbeat(): (QOS_HEARTBEAT, self.motion.on_heartbeat_payload),
                self.topics.site(): (QOS_SITE, self.motion.on_site_payload),
                self.topics.poses(): (QOS_POSES, self.motors.on_poses_payload),
            },
            buffer_size=self.settings.buffer_size,
            reconnect_min_s=self.settings.reconnect_min_s,
            reconnect_max_s=self.settings.reconnect_max_s,
            username=self.settings.username,
            password=self.settings.password.get_secret_value() if self.settings.password else None,
            tls=(self.broker_url or "").lower().startswith(("mqtts://", "ssl://")),
            tls_ca=str(self.settings.tls_ca) if self.settings.tls_ca else None,
        )
        log.info(
            "agent %s (v%s) starting: broker %s, sensors %s, commands %s%s",
            self.robot_id,
            __version__,
            self.broker_url,
            self.supervisor.names,
            self.commands.command_names,
            " [simulated]" if self.world else "",
        )
        self._transport.start()
        self.supervisor.start()
        self._tasks = [
            asyncio.create_task(self._status_refresher(), name="status"),
            asyncio.create_task(self.watchdog.run(), name="link-watchdog"),
            asyncio.create_task(self.clock.run(), name="clock-sync"),
            asyncio.create_task(self.replay.run(), name="replay-ring"),
            asyncio.create_task(self.motion.run(), name="motion"),
        ]
        # tests cut the simulated Lighthouse (a hardware fault) with SIGUSR2 (SIGUSR1: the debug hooks' freeze)
        if self.world is not None:
            with contextlib.suppress(ValueError, RuntimeError, NotImplementedError):  # not the main thread
                loop.add_signal_handler(signal.SIGUSR2, self.world.toggle_lighthouse_blackout)
        # What start-up built (modules, config, detector) lives as long as the agent: frozen, a full garbage
        # collection no longer walks it, so it cannot pause command handling and the motors' deadman long
        gc.freeze()
        try:
            await stop.wait()
        finally:
            await self.shutdown()

    async def shutdown(self) -> None:
        log.info("shutting down")
        for task in self._tasks:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self.commands.stop_all("shutdown")
        await self.supervisor.stop()
        self.legacy.close()
        try:
            self.motors.shutdown()
        except Exception:
            log.exception("closing motors failed")
        if self._transport is not None:
            await self._transport.close(self.status_payload(online=False, reason="shutdown"))
        self.replay.close()
        log.info("stopped")
