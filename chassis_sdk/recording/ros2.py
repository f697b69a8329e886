"""A device's session recorded as a rosbag2 MCAP file, which ROS 2 tools open as a bag
(``ros2 bag info``/``play``, rosbags, Foxglove, PlotJuggler) and which
``chassis-sdk replay``, ``export`` and ``plot`` read back like the Foxglove recording.

Topics, for a device named ``chassis`` (relative names go under the namespace, as the
live ROS 2 bridge's do; types and QoS from
`TOPICS`)::

    odom                           nav_msgs/msg/Odometry     the odometry, odom -> base_link
    /tf                            tf2_msgs/msg/TFMessage    the same sample as a transform
    /tf_static                     tf2_msgs/msg/TFMessage    once at the start, latched (a
                                                             board: base_link -> imu_link)
    battery_state                  sensor_msgs/msg/BatteryState  a board's battery stream,
                                                             or a chassis's voltage at 1 Hz
    imu/data_raw                   sensor_msgs/msg/Imu       a board's IMU
    chassis_sdk/chassis/raw/rx     std_msgs/msg/UInt8MultiArray  the bytes as they arrived
    chassis_sdk/chassis/raw/tx     std_msgs/msg/UInt8MultiArray  every frame the host wrote

What makes it a rosbag2 file, as ``rosbag2_storage_mcap`` writes one: the header's
profile ``ros2``; per type a ``ros2msg`` schema (the full definition text,
`definition`); per topic a channel with message
encoding ``cdr`` (what ``serialize()`` gives: plain CDR after the encapsulation header
``00 01 00 00``) and the metadata ``offered_qos_profiles`` (`offered_qos_profiles`,
rosbag2's v9 YAML) and ``topic_type_hash`` (REP 2011). Log and publish times are the
receive time in epoch nanoseconds; header stamps are wall-clock time. It is written
with ``mcap``'s own writer: ``mcap_ros2``'s writes neither QoS nor type hashes.

There is deliberately no ``rosbag2`` metadata record: rosbag2 reads the QoS YAML by that
record's ``serialized_metadata`` version, and without one takes its own (Jazzy's v9,
which this YAML is). The session's ``chassis_sdk`` record (device, port, versions) is
there, as in the Foxglove recording, so the device is known when reading back.

What a hard kill loses: the chunk is finished and flushed every ``flush_interval``
(1 s), as [`McapRecording`][chassis_sdk.recording.mcap.McapRecording] does.

The recorder is chosen with `rosbag` (``record=rosbag("run.mcap")`` on a device,
``capture.record(port, rosbag(...))``), with
[`open_recording`][chassis_sdk.recording.open_recording] (``ros2=True``) or by building a
`Ros2Recording`. Needs the ``ros2`` extra (``cyclonedds``, ``mcap``).
"""

from __future__ import annotations

import importlib.util
import logging
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from ..core.notifier import Notifier
from ..core.validation import check_real
from ..errors import install_hint
from .batch import AfterFrame
from .mcap import FLUSH_INTERVAL
from .sink import session_metadata

if TYPE_CHECKING:
    from ..core.device import Device
    from .ros2_types import Ros2Options, StaticTransform, TopicSpec

__all__ = ["Ros2Recording", "Rosbag", "offered_qos_profiles", "rosbag"]

_log = logging.getLogger("chassis_sdk.recording")
_NS = 1_000_000_000
#: rmw's "infinite" duration, as rosbag2 writes a default publisher's deadline, lifespan
#: and lease (``RMW_DURATION_INFINITE``: INT64_MAX nanoseconds).
_INFINITE = (9223372036, 854775807)
#: The history depth of the raw-bytes topics (about a second of chunks).
_RAW_DEPTH = 100


def _needs_ros2(what: str) -> ImportError:
    return ImportError(f"{what} needs cyclonedds and mcap: {install_hint('ros2')}")


def offered_qos_profiles(spec: TopicSpec) -> str:
    """The ``offered_qos_profiles`` of a topic as rosbag2 writes it in a channel's
    metadata (metadata version 9, as Jazzy writes it): a YAML list with one profile, the
    policies by name, the durations as ``{sec, nsec}`` (unset ones: rmw's infinite)."""
    sec, nsec = _INFINITE
    duration = f"\n    sec: {sec}\n    nsec: {nsec}"
    return (
        "- history: keep_last\n"
        f"  depth: {spec.depth}\n"
        f"  reliability: {spec.reliability}\n"
        f"  durability: {spec.durability}\n"
        f"  deadline:{duration}\n"
        f"  lifespan:{duration}\n"
        "  liveliness: automatic\n"
        f"  liveliness_lease_duration:{duration}\n"
        "  avoid_ros_namespace_conventions: false"
    )


# --- the choice: a file path that carries its options -------------------------------------


@dataclass(frozen=True, eq=False)
class Rosbag:
    """A rosbag2 recording to be made: the file and the options, checked when made (see
    `rosbag`, which makes one). It is a path (``os.fspath`` gives the file), so it
    goes wherever a recording's file does, and it opens its recorder itself
    (`open_recorder`): the device's ``record`` option and
    `chassis_sdk.recording.capture.record` take it as they take a file name.

    Attributes:
        path: The ``.mcap`` file (overwritten).
        ros: The names, frames, static transforms and covariances, as the live ROS 2
            bridge takes them (`Ros2Options`).
        flush_interval: Seconds between two flushes of the file (what a kill can lose).
        metadata: Added to the session's ``chassis_sdk`` metadata record.
    """

    path: Path
    ros: Ros2Options
    flush_interval: float = FLUSH_INTERVAL
    metadata: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.path, Path):
            raise TypeError(f"path must be a pathlib.Path, got {type(self.path).__name__}")
        if self.path.suffix.lower() != ".mcap":
            raise ValueError(
                f"a rosbag2 recording is an MCAP file: name it *.mcap, got {str(self.path)!r}"
            )
        if self.path.is_dir():
            raise ValueError(f"the recording must be a file, got the directory {str(self.path)!r}")
        interval = check_real(self.flush_interval, "flush_interval", low=0, low_open=True, unit="s")
        object.__setattr__(self, "flush_interval", interval)
        if not isinstance(self.metadata, Mapping) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in self.metadata.items()
        ):
            raise TypeError(f"metadata must map str to str, got {self.metadata!r}")
        object.__setattr__(self, "metadata", dict(self.metadata))

    @property
    def namespace(self) -> str:
        """Where the relative topics go, normalised (``/robot1``; ``""``: none)."""
        return self.ros.namespace

    def __fspath__(self) -> str:
        """The file."""
        return str(self.path)

    def open_recorder(self, device: Device[Any, Any]) -> Ros2Recording:
        """Start recording ``device``'s session to `path` (what a device's
        ``record`` option calls as it connects)."""
        return Ros2Recording(self.path, device, options=self)


def rosbag(
    path: str | os.PathLike[str],
    *,
    namespace: str = "",
    frame_id: str = "odom",
    child_frame_id: str = "base_link",
    imu_frame_id: str = "imu_link",
    static_transforms: Sequence[StaticTransform] | None = None,
    pose_covariance: Sequence[float] | None = None,
    twist_covariance: Sequence[float] | None = None,
    flush_interval: float = FLUSH_INTERVAL,
    metadata: Mapping[str, str] | None = None,
    frame_prefix: str | None = None,
) -> Rosbag:
    """Choose a rosbag2 recording (the ROS 2 profile of MCAP) where a recording's file
    goes: a device's ``record`` option or `chassis_sdk.recording.capture.record`.

    ```python
    from chassis_sdk.recording.ros2 import rosbag

    async with Chassis("/dev/ttyUSB0", record=rosbag("run.mcap", namespace="robot1")) as robot:
        ...
    # ros2 bag info run.mcap: /robot1/odom, /tf, /robot1/battery_state, ...
    ```

    Args:
        path: The ``.mcap`` file (overwritten when the recording starts).
        namespace: Where the relative topics go (``robot1`` → ``/robot1/odom``).
        frame_id, child_frame_id, imu_frame_id, static_transforms, pose_covariance,
            twist_covariance, frame_prefix: See
            `Ros2Options` (``/tf_static``
            is written once at the start, and only when it holds something).
        flush_interval, metadata: See `Rosbag`.

    Raises:
        TypeError: An option of the wrong type.
        ValueError: A name that is not ``*.mcap``, a bad namespace, frame, covariance or
            interval; all before anything is opened.
        ImportError: cyclonedds or mcap missing (the ``ros2`` extra).
    """
    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"path must be a file path, got {type(path).__name__}")
    if not str(path):
        raise ValueError("path must be a file path, got ''")
    for package in ("cyclonedds", "mcap"):
        if importlib.util.find_spec(package) is None:
            raise _needs_ros2("recording a rosbag2 file")
    from .ros2_types import Ros2Options

    ros = Ros2Options(
        namespace=namespace,
        frame_id=frame_id,
        child_frame_id=child_frame_id,
        imu_frame_id=imu_frame_id,
        static_transforms=static_transforms,
        pose_covariance=pose_covariance,
        twist_covariance=twist_covariance,
        frame_prefix=frame_prefix,
    )
    return Rosbag(
        Path(path),
        ros,
        flush_interval=flush_interval,
        metadata={} if metadata is None else metadata,
    )


# --- the recorder --------------------------------------------------------------------------


@dataclass
class _Channel:
    id: int
    sequence: int = 0


class Ros2Recording:
    """A session written as a rosbag2 MCAP file (see the module docstring for the
    topics and what makes it one). It watches the device through a
    [`Notifier`][chassis_sdk.core.notifier.Notifier] (every byte both ways, every message
    of its odometry, IMU, battery and telemetry streams, synchronously, so nothing is
    missed); the serialising and writing are done in one batch after the application's
    tasks woken by the same frame have run, as the Foxglove recorder does.

    Args:
        path: The ``.mcap`` file (overwritten).
        device: The device whose session this is.
        options: The options, checked (`rosbag` makes them); or give them as
            keywords (those of `rosbag`), not both.

    Raises:
        TypeError, ValueError, ImportError: As `rosbag`.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        device: Device[Any, Any],
        *,
        options: Rosbag | None = None,
        **keywords: Any,
    ) -> None:
        if options is None:
            options = rosbag(path, **keywords)
        elif keywords or Path(path) != options.path:
            raise TypeError("give Ros2Recording its options as keywords or as options=, not both")
        from mcap.writer import CompressionType, Writer

        from .._version import __version__
        from . import ros2_types as msg

        self._msg = msg
        self._raw_type: Any = msg.UInt8MultiArray  # its IDL annotations are not types
        self.options = options
        self.path = options.path
        self.device = device
        #: Messages written so far.
        self.messages = 0
        self._closed = False
        # Monotonic seconds -> epoch nanoseconds, fixed once per session (as the sink).
        self._epoch_offset = time.time_ns() - int(time.monotonic() * _NS)
        self._last_flush = time.monotonic()
        self._after = AfterFrame(str(self.path))
        self._later = self._after.later
        self._notifier: Notifier | None = None
        self._file: IO[bytes] = self.path.open("wb")
        try:
            self._writer = Writer(self._file, compression=CompressionType.ZSTD)
            self._writer.start(profile="ros2", library=f"chassis_sdk {__version__}")
            # mcap >= 1.6 finishes the open chunk on flush(); an older one can only
            # flush the file, and then a kill loses up to a chunk (1 MiB).
            self._flush: Callable[[], None] = getattr(self._writer, "flush", self._file.flush)
            info = session_metadata(device)
            info.update(options.metadata)
            self._writer.add_metadata("chassis_sdk", info)
            self._schemas: dict[type, int] = {}
            self._attach()
        except BaseException:
            if self._notifier is not None:
                self._notifier.close()
            self._file.close()
            raise

    # --- the topics ----------------------------------------------------------------------------

    def _channel(self, spec: TopicSpec) -> _Channel:
        msg = self._msg
        schema = self._schemas.get(spec.type)
        if schema is None:
            schema = self._schemas[spec.type] = self._writer.register_schema(
                msg.ros_name(spec.type), "ros2msg", msg.definition(spec.type).encode()
            )
        return _Channel(
            self._writer.register_channel(
                spec.qualified(self.options.namespace),
                "cdr",
                schema,
                {
                    "offered_qos_profiles": offered_qos_profiles(spec),
                    "topic_type_hash": msg.type_hash(spec.type),
                },
            )
        )

    def _attach(self) -> None:
        msg = self._msg
        notifier = self._notifier = Notifier(self.device)  # closed with the recording
        raw = f"chassis_sdk/{self.device.device_name}/raw"
        self._rx = self._channel(msg.TopicSpec(f"{raw}/rx", msg.UInt8MultiArray, "out",
                                               depth=_RAW_DEPTH))  # fmt: skip
        self._tx = self._channel(msg.TopicSpec(f"{raw}/tx", msg.UInt8MultiArray, "out",
                                               depth=_RAW_DEPTH))  # fmt: skip
        translator = self._translator = msg.Translator(
            self.options.ros,
            notifier.stream_names,
            battery=self.device.battery_model,
        )
        self._channels = {key: self._channel(msg.TOPICS[key]) for key in translator.topics}
        for stream in translator.streams:
            notifier.listen(stream, self._queued(stream))
        if translator.static:
            channel = self._channel(msg.TOPICS["tf_static"])
            self._write(channel, translator.static_message(time.time()), time.monotonic())
        notifier.add_tap(self)

    # --- what is written -------------------------------------------------------------------------

    def rx(self, data: bytes, now: float) -> None:
        """Bytes arrived at ``now`` (the device's tap)."""
        self._later(self._raw, self._rx, data, now)

    def tx(self, data: bytes, now: float) -> None:
        """The frame ``data`` began to leave at ``now`` (the device's tap)."""
        self._later(self._raw, self._tx, data, now)

    def link_state(self, state: str, now: float) -> None:
        """The link went to ``state``: not written (ROS 2 has no message for it; the
        Foxglove and JSON-lines recordings keep it)."""

    def _queued(self, stream: str) -> Callable[[Any], None]:
        def listener(reading: Any) -> None:
            self._later(self._reading, stream, reading, time.monotonic())

        return listener

    def _reading(self, stream: str, reading: Any, now: float) -> None:
        for key, message in self._translator.messages(stream, reading):
            self._write(self._channels[key], message, now)

    def _raw(self, channel: _Channel, data: bytes, now: float) -> None:
        self._write(channel, self._raw_type(data=bytes(data)), now)

    def _write(self, channel: _Channel, message: Any, now: float) -> None:
        log_time = int(now * _NS) + self._epoch_offset
        self._writer.add_message(
            channel.id, log_time=log_time, data=message.serialize(), publish_time=log_time,
            sequence=channel.sequence,
        )  # fmt: skip
        channel.sequence += 1
        self.messages += 1
        if now - self._last_flush >= self.options.flush_interval:
            self._last_flush = now
            self._flush()

    def close(self) -> None:
        """Write what is queued, stop watching the device and finish the file (its
        summary: the index that ``ros2 bag`` reads); safe to call twice."""
        if self._closed:
            return
        self._after.close()
        self._closed = True
        if self._notifier is not None:
            self._notifier.close()
        try:
            self._writer.finish()  # type: ignore[no-untyped-call]
        finally:
            self._file.close()
