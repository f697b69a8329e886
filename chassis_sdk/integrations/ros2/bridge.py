"""The robot on the ROS 2 graph, without ROS: `Ros2Bridge` puts one device on
DDS with ROS 2's names, types and QoS, so that Nav2, teleop, RViz, robot_localization
and ``ros2 bag`` work with it as with any ROS 2 base driver. Needs the ``ros2`` extra
(``cyclonedds``); no ROS installation.

Topics (relative names go under the namespace; types in
`chassis_sdk.recording.ros2_types`):

===================  ==========================  ===  ==========================================
ROS name             type                        dir  what
===================  ==========================  ===  ==========================================
``cmd_vel``          ``geometry_msgs/Twist``     in   each sample one fresh ``set_velocity``
                     (``TwistStamped``:          (best effort: any writer matches)
                     ``stamped=True``)
``emergency_stop``   ``std_msgs/Bool``           in   ``true`` engages, ``false`` releases
``odom``             ``nav_msgs/Odometry``       out  the device's odometry, at its rate
``/tf``              ``tf2_msgs/TFMessage``      out  odom → base_link (``tf=False``: none)
``/tf_static``       ``tf2_msgs/TFMessage``      out  the static transforms (latched)
``battery_state``    ``sensor_msgs/BatteryState`` out the battery voltage (1 Hz for a chassis)
``/diagnostics``     ``DiagnosticArray``         out  the device's health, 1 Hz
``imu/data_raw``     ``sensor_msgs/Imu``         out  a board's IMU (m/s², rad/s)
``robot_description`` ``std_msgs/String``        out  a URDF made from the device (latched)
``joint_states``     ``sensor_msgs/JointState``  out  the wheels' angles and speeds (a chassis)
===================  ==========================  ===  ==========================================

``robot_description`` and ``joint_states`` let robot_state_publisher and RViz draw the
base with no description package (`description.urdf`); ``description=False`` leaves
both to the user's own.

Why it is shaped this way
-------------------------
It keeps the contract of every surface that can move the robot (the MQTT bridge's):

- each ``cmd_vel`` sample is one fresh command under the deadman: it holds for
  ``command_timeout`` (0.5 s, diff_drive_controller's ``cmd_vel_timeout``) and then the
  robot stops, unless a newer sample came; a writer that stays alive and silent stops
  the robot within the deadman, and when no ``cmd_vel`` writer is left (DDS tells the
  reader: liveliness and matching) the robot stops at once;
- velocity is state, not a queue: every valid sample goes to the device's motion core
  through its writer's source (kind ``"ros2"``, one per ``cmd_vel`` writer, told apart
  by the sample's publication handle: two writers do not drive against each other);
  the core writes the newest at most once per ``WRITE_PERIOD`` (20 ms), and a stamped
  sample holds only for what is left of ``command_timeout`` after its stamp;
- a sample that is non-finite, out of the device's range, stamped older than the
  deadman, or that will not decode is refused, counted and reported in the log (the
  first at once, then at most one summary a second) and in ``/diagnostics``: never
  acted on, and nothing a sample holds can end the bridge;
- ``emergency_stop`` never waits behind velocity, and while it is engaged the motion
  core refuses velocity (from every source); once released, ``cmd_vel`` must send a
  zero before it drives again (the core's rule for a streaming source: releasing an
  e-stop restarts nothing); ``read_only`` subscribes to nothing and never writes to the
  device;
- the bridge ending, for any reason, stops the robot (then its DDS endpoints are
  deleted, so peers learn at once that it is gone);
- stamps are wall-clock time.

What goes out comes by callback (``chassis_sdk.core.Notifier(device).listen``), not by a
task per stream: each reading is queued inside the device's read path (per stream at most
the device's ``queue_size``; past it the oldest is dropped and counted in
``dropped_readings``) and one task publishes every queue in order. Writes never block,
so that task empties the queues each time it runs; a DDS reader that lags loses
messages to its writer's history (``dropped_writes``), never holds up the device.

No ROS services: between rmw_cyclonedds and rmw_fastrtps they do not interoperate
(ros2/rmw_cyclonedds #184, #503, #577), and parameters are services. Stop and e-stop
are topics, configuration is the CLI's.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import time
from collections import deque
from collections.abc import Callable, Coroutine, Sequence
from typing import Any

import anyio
from cyclonedds.core import DDSException

from ...core.device import Device
from ...core.geometry import Geometry
from ...core.notifier import Notifier
from ...core.supervisor import ConnectionState
from ...core.validation import check_real
from ...errors import ChassisError, ConnectionLostError, NotConnectedError
from ...recording import ros2_types as msg
from ...recording.ros2_types import TOPICS, Ros2Options, StaticTransform, Translator
from ..inbound import Refusals
from .commands import Inbound
from .dds import Discovery, Participant, Reader, Writer, discovery_from_env
from .description import urdf

__all__ = ["Ros2Bridge", "StaticTransform"]

_log = logging.getLogger("chassis_sdk.integrations.ros2")
#: The longest a ``diagnose()`` may take before the status says so.
_DIAGNOSE_TIMEOUT = 2.0


class Ros2Bridge:
    """One device on the ROS 2 graph (see the module docstring for the topics and the
    safety rules).

    Args:
        device: A connected (or connecting) device; the bridge never closes it.
        namespace: Where the relative topics go (``robot1`` → ``/robot1/odom``).
        discovery: How to find peers (default: ROS 2's variables,
            [`discovery_from_env`][chassis_sdk.integrations.ros2.dds.discovery_from_env]).
        stamped: Read ``cmd_vel`` as ``geometry_msgs/TwistStamped`` (Jazzy's
            diff_drive_controller); a stamped sample older than ``command_timeout``
            is refused.
        tf: Publish odom → base_link on ``/tf`` (``False`` when an EKF publishes it).
        read_only: Subscribe to nothing: never move the robot, never write to it.
        command_timeout: How long one ``cmd_vel`` sample holds (s).
        max_linear: Clamp ``linear.x`` to this (m/s; ``None``: the device's range).
        max_angular: Clamp ``angular.z`` to this (rad/s).
        frame_id: The odometry frame (REP 105: ``odom``).
        child_frame_id: The robot's frame (``base_link``).
        imu_frame_id: A board's IMU frame.
        pose_covariance: Six variances (x, y, z, roll, pitch, yaw) for the pose;
            default `DEFAULT_POSE_COVARIANCE`.
        twist_covariance: The same for the twist.
        static_transforms: What ``/tf_static`` holds (default: a board's
            ``base_link`` → ``imu_link``, identity; a chassis none).
        diagnostics_period: Seconds between two ``/diagnostics`` messages.
        frame_prefix: Put before every frame name (``None``: the namespace's,
            ``robot1/``; ``""``: none): two robots share one ``/tf`` tree.
        description: Publish ``robot_description`` and ``joint_states`` (``False``:
            the user's robot_state_publisher has a description of its own).
        geometry: The base's size for them (``None``: what the device reports when the
            bridge starts, `Device.geometry`; a read-only bridge asks nothing).

    Raises:
        TypeError, ValueError: A bad option (before anything is created).
    """

    def __init__(
        self,
        device: Device[Any, Any],
        *,
        namespace: str = "",
        discovery: Discovery | None = None,
        stamped: bool = False,
        tf: bool = True,
        read_only: bool = False,
        command_timeout: float = 0.5,
        max_linear: float | None = None,
        max_angular: float | None = None,
        frame_id: str = "odom",
        child_frame_id: str = "base_link",
        imu_frame_id: str = "imu_link",
        pose_covariance: Sequence[float] | None = None,
        twist_covariance: Sequence[float] | None = None,
        static_transforms: Sequence[StaticTransform] | None = None,
        diagnostics_period: float = 1.0,
        frame_prefix: str | None = None,
        description: bool = True,
        geometry: Geometry | None = None,
    ) -> None:
        self.device = device
        #: The names, frames and covariances (the rosbag2 recorder takes the same).
        self.options = Ros2Options(
            namespace=namespace,
            frame_id=frame_id,
            child_frame_id=child_frame_id,
            imu_frame_id=imu_frame_id,
            static_transforms=static_transforms,
            pose_covariance=pose_covariance,
            twist_covariance=twist_covariance,
            tf=tf,
            frame_prefix=frame_prefix,
        )
        self.namespace = self.options.namespace
        self.discovery = discovery if discovery is not None else discovery_from_env()
        self.stamped = bool(stamped)
        # A read-only device makes a read-only bridge: it could write nothing anyway.
        self.read_only = bool(read_only) or bool(getattr(device, "read_only", False))
        self.command_timeout = check_real(
            command_timeout, "command_timeout", low=0, low_open=True, high=10, unit="s"
        )
        self.max_linear = (
            None
            if max_linear is None
            else check_real(max_linear, "max_linear", low=0, low_open=True)
        )
        self.max_angular = (
            None
            if max_angular is None
            else check_real(max_angular, "max_angular", low=0, low_open=True)
        )
        self._device_any: Any = device
        if geometry is not None and not isinstance(geometry, Geometry):
            raise TypeError(f"geometry must be a Geometry or None, got {geometry!r}")
        self.description = bool(description)
        #: The base's size (the device's, once the bridge started, unless given).
        self.geometry = geometry
        self.diagnostics_period = check_real(
            diagnostics_period, "diagnostics_period", low=0, low_open=True, unit="s"
        )
        with Notifier(device) as notifier:
            self._streams = notifier.stream_names
        #: What the device's readings give: the topics and each reading's messages.
        self.translator = self._translator()
        self._refusals = Refusals(1.0)
        #: What comes in: ``cmd_vel`` and ``emergency_stop``, through the motion core.
        self.inbound = Inbound(
            device,
            self.namespace,
            stamped=self.stamped,
            command_timeout=self.command_timeout,
            max_linear=self.max_linear,
            max_angular=self.max_angular,
            refuse=self._refuse,
        )
        self._cmd: Reader[Any] | None = None
        self._estop: Reader[Any] | None = None
        #: Set once the DDS endpoints exist (the bridge is on the graph).
        self.started = anyio.Event()
        #: Odometry messages published.
        self.odometry_published = 0
        #: Readings dropped before they were published (the oldest first): the
        #: publisher fell the device's ``queue_size`` readings of one stream behind.
        self.dropped_readings = 0
        self._writers: list[Writer[Any]] = []
        # The readings not yet published, per stream (filled by the device's read path),
        # the publisher's wake, and whether the link was lost for good.
        self._queued: dict[str, deque[Any]] = {}
        self._ready = asyncio.Event()
        self._lost = False

    def _translator(self) -> Translator:
        # The device's battery model (if any) gives BatteryState.percentage.
        return Translator(
            self.options,
            self._streams,
            battery=self.device.battery_model,
            forward_only=True,
            geometry=self.geometry if self.description else None,
        )

    async def _read_geometry(self) -> None:
        """The device's size, for ``robot_description`` and ``joint_states``."""
        if not self.description or self.geometry is not None or self.read_only:
            return
        try:
            self.geometry = await self.device.geometry()
        except ChassisError as exc:
            _log.warning("robot_description: the device's size could not be read (%s)", exc)
        if self.geometry is not None:
            self.translator = self._translator()

    @property
    def commands(self) -> int:
        """``cmd_vel`` samples taken by the device's motion core (it writes the newest
        at most once per ``WRITE_PERIOD``)."""
        return self.inbound.commands

    @property
    def writer_gone_stops(self) -> int:
        """Stops because the last ``cmd_vel`` writer went away."""
        return self.inbound.writer_gone_stops

    @property
    def refused(self) -> int:
        """Samples refused so far (each counted and reported in the log, summarised)."""
        return self._refusals.total

    @property
    def dropped_writes(self) -> int:
        """Messages DDS did not take (a lagging reader's full history): never waited for."""
        return sum(w.dropped for w in self._writers)

    # --- lifetime --------------------------------------------------------------------------

    async def run(self) -> None:
        """Bridge until cancelled. The robot is stopped (zero written) whenever this
        returns or raises, unless ``read_only``; then the DDS endpoints are deleted.

        Raises:
            ChassisError: DDS could not start (a bad configuration), or the device's
                link was lost for good (``ConnectionLostError``: lost without
                ``reconnect``, after what came before it was published;
                ``NotConnectedError``: the device was not open when the bridge
                started).
            ValueError: This process has the domain configured otherwise already.
        """
        loop = asyncio.get_running_loop()
        self.discovery = await self.discovery.resolved()  # a name Cyclone cannot use aborts it
        await self._read_geometry()
        try:
            participant = Participant(self.discovery, self.namespace)
        except DDSException as exc:
            raise ChassisError(
                f"cannot join DDS domain {self.discovery.domain_id}: {exc}"
            ) from None
        notifier = Notifier(self.device)
        try:
            loops = self._setup(participant, loop, notifier)
            self.started.set()
            _log.info(
                "on the ROS 2 graph: domain %d, %s discovery, namespace %r%s",
                self.discovery.domain_id,
                self.discovery.range.lower(),
                self.namespace or "/",
                " (read-only)" if self.read_only else "",
            )
            async with anyio.create_task_group() as tg:
                for name, work in loops:
                    tg.start_soon(work, name=f"ros2 {name}")
        finally:
            notifier.close()  # nothing more is queued
            with anyio.CancelScope(shield=True):
                await self._stop_robot()
            self.inbound.end()
            participant.close()

    def _setup(
        self, participant: Participant, loop: asyncio.AbstractEventLoop, notifier: Notifier
    ) -> list[tuple[str, Callable[[], Coroutine[Any, Any, None]]]]:
        translator = self.translator
        out = {key: participant.writer(TOPICS[key]) for key in translator.topics}
        diagnostics = participant.writer(TOPICS["diagnostics"])
        self._writers += [*out.values(), diagnostics]
        if translator.static:
            static = participant.writer(TOPICS["tf_static"])
            self._writers.append(static)
            static.write(translator.static_message(time.time()))
        if self.description:
            described = participant.writer(TOPICS["robot_description"])
            self._writers.append(described)
            name = type(self.device).__name__.lower()
            text = urdf(self.geometry, self.options, self._streams, name=name)
            described.write(msg.String(data=text))
        self._ready = asyncio.Event()
        self._lost = False
        self._queued = {}
        for stream in translator.streams:
            notifier.listen(stream, self._queue(stream))
        notifier.listen_states(self._link_state)
        loops: list[tuple[str, Callable[[], Coroutine[Any, Any, None]]]] = [
            ("publish", functools.partial(self._publish, out)),
            ("diagnostics", lambda: self._diagnostics(diagnostics)),
        ]
        if not self.read_only:
            inbound = self.inbound
            cmd = participant.reader(TOPICS["cmd_vel_stamped" if self.stamped else "cmd_vel"], loop)
            cmd.on_no_writers = inbound.writer_gone
            self._cmd = cmd
            estop = participant.reader(TOPICS["emergency_stop"], loop)
            self._estop = estop
            for reader in (cmd, estop):  # counted and reported with the other refusals
                reader.on_undecodable = functools.partial(self._refuse, reader.name)
            loops += [
                ("cmd_vel", lambda: inbound.commands_from(cmd)),
                ("estop", lambda: inbound.estops_from(estop)),
            ]
        return loops

    async def _stop_robot(self) -> None:
        if self.read_only:
            return  # a viewer never writes to the device, not even a zero
        with contextlib.suppress(ChassisError):
            await self.device.stop()

    # --- what comes in ---------------------------------------------------------------------

    def _refuse(self, where: str, why: str) -> None:
        report = self._refusals.add(where, why)
        if report is not None:
            _log.warning("refused: %s", report.summary())

    # --- what goes out ---------------------------------------------------------------------

    def _queue(self, stream: str) -> Callable[[Any], None]:
        """The callback that takes ``stream``'s readings, inside the device's read path:
        it queues each (at most ``queue_size``, the oldest dropped and counted) and wakes
        the publisher; it never raises and never waits."""
        readings: deque[Any] = deque(maxlen=self.device.queue_size)
        self._queued[stream] = readings
        ready = self._ready

        def queue(reading: Any) -> None:
            if len(readings) == readings.maxlen:
                self.dropped_readings += 1
            readings.append(reading)
            ready.set()

        return queue

    def _link_state(self, state: ConnectionState) -> None:
        """A state change (in the read path or the supervisor): a link lost for good
        ends the publisher, after what was queued."""
        if state is ConnectionState.LOST:
            self._lost = True
            self._ready.set()

    def _check_link(self) -> None:
        state = self.device.connection_state
        if state is ConnectionState.LOST or self._lost:
            raise ConnectionLostError(f"lost connection to {self.device.port} (no reconnect)")
        if state is ConnectionState.DISCONNECTED:
            raise NotConnectedError(f"{self.device.port} is not connected; use `async with` first")

    async def _publish(self, out: dict[str, Writer[Any]]) -> None:
        """Every reading of every stream, in order, as the messages the translator makes
        of it: one task for all the streams, woken by their callbacks (writes never
        block, so it empties the queues each time it runs)."""
        translator = self.translator
        queued = self._queued
        ready = self._ready
        self._check_link()
        while True:
            await ready.wait()
            ready.clear()
            for stream, readings in queued.items():
                while readings:
                    for key, message in translator.messages(stream, readings.popleft()):
                        out[key].write(message)
                        if key == "odom":
                            self.odometry_published += 1
            if self._lost:
                self._check_link()

    async def _diagnostics(self, diagnostics: Writer[Any]) -> None:
        name = f"chassis_sdk: {self.device.device_name}"
        while True:
            level, message, values = await self._health()
            pending = self._refusals.due()
            if pending is not None:
                _log.warning("refused: %s", pending.summary())
            if self.refused:
                values.append(("refused", str(self.refused)))
            diagnostics.write(
                msg.diagnostics_message(
                    time.time(),
                    name=name,
                    hardware_id=self.device.port,
                    level=level,
                    message=message,
                    values=values,
                )
            )
            await anyio.sleep(self.diagnostics_period)

    async def _health(self) -> tuple[int, str, list[tuple[str, str]]]:
        """The device's health as a level, one line and key/value pairs. A read-only
        bridge sends no request (a viewer never writes): it reports the link only."""
        device = self.device
        stats = device.stats
        values = [
            ("connection", device.connection_state.value),
            ("frames in", str(stats.frames)),
            ("frames out", str(stats.frames_sent)),
            ("checksum errors", str(stats.checksum_errors)),
            ("reconnects", str(stats.reconnects)),
        ]
        acted = device.reflexes_acted
        if acted:  # the reflexes that acted, and the last (what, what it did, measured)
            values.append(("reflexes", ", ".join(f"{k} {n}" for k, n in sorted(acted.items()))))
            values.append(("last reflex", str(device.last_reflex)))
        if not device.is_connected:
            return msg.DIAGNOSTIC_STALE, f"not connected ({device.connection_state.value})", values
        if self.read_only:
            return msg.DIAGNOSTIC_OK, "connected (read-only: no health request)", values
        try:
            with anyio.fail_after(_DIAGNOSE_TIMEOUT):
                report = await self._device_any.diagnose()
        except (TimeoutError, ChassisError) as exc:
            return msg.DIAGNOSTIC_WARN, f"diagnose failed: {exc}", values
        values += [(f"fault {i + 1}", f) for i, f in enumerate(report.faults)]
        values += [(f"note {i + 1}", n) for i, n in enumerate(report.notes)]
        if report.faults:
            return msg.DIAGNOSTIC_ERROR, "; ".join(report.faults)[:200], values
        return msg.DIAGNOSTIC_OK, "OK", values
