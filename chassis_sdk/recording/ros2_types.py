"""ROS 2 messages without ROS: the types the ROS 2 bridge and the rosbag2 recorder use,
with their message definitions, type hashes and topics, in one place.

Each type is a Cyclone DDS ``IdlStruct`` in ROS 2's DDS shape (``rosidl``'s mapping:
the DDS type of ``geometry_msgs/msg/Twist`` is ``geometry_msgs::msg::dds_::Twist_``,
and its fields are the ``.msg`` file's, in order), so the same class is what the
bridge puts on the wire (plain CDR, encapsulation ``00 01 00 00``) and what a rosbag2
MCAP file holds. From the fields alone this module derives what ROS 2 tools check:

* `definition`: the full message definition text that rosbag2 stores as a
  ``ros2msg`` schema, made as rosbag2 makes it: the type's ``.msg`` file as it is
  (comments, constants and defaults), then each type it uses after a line of 80 ``=``
  and ``MSG: pkg/Type`` (the ``.msg`` files are ROS 2 Jazzy's, in ``ros2_msg/``);
* `type_hash`: the ``RIHS01_…`` type hash of REP 2011 that Jazzy and newer put in
  every endpoint's USER_DATA (``typehash=…;``) and in a bag's ``topic_type_hash``.

Both are checked against an independent source (``rosbags``' Jazzy type store: the
fields each ``.msg`` file declares, and the hash) by ``tests/test_ros2_types.py``, as
are the bytes of each serialised message.

`TOPICS` names every topic the bridge offers and the recorder writes, with its
type and QoS; the converters (`odometry_message`, `transform_message`, ...)
turn what a device reports into these messages. Stamps are wall-clock time, as ROS
expects (``wall_time`` converts a reading's ``time.monotonic()`` timestamp).

Needs the ``ros2`` extra (``cyclonedds``).
"""

import dataclasses
import hashlib
import importlib.resources
import json
import math
import re
import time
import typing
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Final, Literal

from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t

from ..core.battery import OCV_CURVES, BatteryModel
from ..core.geometry import Geometry
from ..core.plain import wall_time

__all__ = [
    "BATTERY_PERIOD",
    "BATTERY_STATUS_UNKNOWN",
    "BATTERY_TECHNOLOGY",
    "DEFAULT_POSE_COVARIANCE",
    "DEFAULT_TWIST_COVARIANCE",
    "DIAGNOSTIC_ERROR",
    "DIAGNOSTIC_OK",
    "DIAGNOSTIC_STALE",
    "DIAGNOSTIC_WARN",
    "JOINT_GAP",
    "TOPICS",
    "BatteryState",
    "Bool",
    "DiagnosticArray",
    "DiagnosticStatus",
    "Header",
    "Imu",
    "JointState",
    "KeyValue",
    "MultiArrayDimension",
    "MultiArrayLayout",
    "Odometry",
    "Point",
    "Pose",
    "PoseWithCovariance",
    "Quaternion",
    "Ros2Options",
    "StaticTransform",
    "String",
    "TFMessage",
    "Time",
    "TopicSpec",
    "Transform",
    "TransformStamped",
    "Translator",
    "Twist",
    "TwistStamped",
    "TwistWithCovariance",
    "UInt8MultiArray",
    "Vector3",
    "battery_message",
    "charge_message",
    "check_frame",
    "check_namespace",
    "covariance",
    "definition",
    "diagnostics_message",
    "imu_message",
    "odometry_message",
    "ros_name",
    "stamp",
    "static_transforms_message",
    "transform_message",
    "type_hash",
    "wall_time",
]

# --- the types (field names and order exactly as the .msg files of ROS 2 Jazzy) --------------

#: ROS's ``byte`` is an octet on the wire; cyclonedds 0.10 has no ``types.byte``, so
#: it is a ``uint8`` there, and :data:`_ROS_BYTES` says which fields ROS calls ``byte``.
_octet = getattr(t, "byte", t.uint8)


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    """``builtin_interfaces/msg/Time``."""

    sec: t.int32 = 0
    nanosec: t.uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    """``std_msgs/msg/Header``."""

    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Bool(IdlStruct, typename="std_msgs::msg::dds_::Bool_"):
    """``std_msgs/msg/Bool``."""

    data: bool = False


@dataclass
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    """``std_msgs/msg/String``: ``robot_description``'s URDF."""

    data: str = ""


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    """``geometry_msgs/msg/Vector3``."""

    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    """``geometry_msgs/msg/Point``."""

    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    """``geometry_msgs/msg/Quaternion`` (the identity by default, as in ROS)."""

    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0
    w: t.float64 = 1.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    """``geometry_msgs/msg/Pose``."""

    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    """``geometry_msgs/msg/PoseWithCovariance``."""

    pose: Pose = field(default_factory=Pose)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    """``geometry_msgs/msg/Twist``: what Nav2 and teleop send on ``cmd_vel``."""

    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class TwistStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TwistStamped_"):
    """``geometry_msgs/msg/TwistStamped`` (Jazzy's diff_drive_controller takes it)."""

    header: Header = field(default_factory=Header)
    twist: Twist = field(default_factory=Twist)


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    """``geometry_msgs/msg/TwistWithCovariance``."""

    twist: Twist = field(default_factory=Twist)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    """``geometry_msgs/msg/Transform``."""

    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    """``geometry_msgs/msg/TransformStamped``."""

    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    """``tf2_msgs/msg/TFMessage``: what ``/tf`` and ``/tf_static`` carry."""

    transforms: t.sequence[TransformStamped] = field(default_factory=list)


@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    """``nav_msgs/msg/Odometry``."""

    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@dataclass
class BatteryState(IdlStruct, typename="sensor_msgs::msg::dds_::BatteryState_"):
    """``sensor_msgs/msg/BatteryState``; what is not measured is NaN, as it documents."""

    header: Header = field(default_factory=Header)
    voltage: t.float32 = math.nan
    temperature: t.float32 = math.nan
    current: t.float32 = math.nan
    charge: t.float32 = math.nan
    capacity: t.float32 = math.nan
    design_capacity: t.float32 = math.nan
    percentage: t.float32 = math.nan
    power_supply_status: t.uint8 = 0
    power_supply_health: t.uint8 = 0
    power_supply_technology: t.uint8 = 0
    present: bool = True
    cell_voltage: t.sequence[t.float32] = field(default_factory=list)
    cell_temperature: t.sequence[t.float32] = field(default_factory=list)
    location: str = ""
    serial_number: str = ""


@dataclass
class Imu(IdlStruct, typename="sensor_msgs::msg::dds_::Imu_"):
    """``sensor_msgs/msg/Imu``."""

    header: Header = field(default_factory=Header)
    orientation: Quaternion = field(default_factory=Quaternion)
    orientation_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    angular_velocity: Vector3 = field(default_factory=Vector3)
    angular_velocity_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    linear_acceleration: Vector3 = field(default_factory=Vector3)
    linear_acceleration_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    """``sensor_msgs/msg/JointState``: the wheels' angles (rad) and speeds (rad/s)."""

    header: Header = field(default_factory=Header)
    name: t.sequence[str] = field(default_factory=list)
    position: t.sequence[t.float64] = field(default_factory=list)
    velocity: t.sequence[t.float64] = field(default_factory=list)
    effort: t.sequence[t.float64] = field(default_factory=list)


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    """``diagnostic_msgs/msg/KeyValue``."""

    key: str = ""
    value: str = ""


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    """``diagnostic_msgs/msg/DiagnosticStatus`` (``level``: `DIAGNOSTIC_OK`, ...)."""

    level: _octet = 0
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: t.sequence[KeyValue] = field(default_factory=list)


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    """``diagnostic_msgs/msg/DiagnosticArray``: what ``/diagnostics`` carries."""

    header: Header = field(default_factory=Header)
    status: t.sequence[DiagnosticStatus] = field(default_factory=list)


@dataclass
class MultiArrayDimension(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayDimension_"):
    """``std_msgs/msg/MultiArrayDimension``."""

    label: str = ""
    size: t.uint32 = 0
    stride: t.uint32 = 0


@dataclass
class MultiArrayLayout(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayLayout_"):
    """``std_msgs/msg/MultiArrayLayout``."""

    dim: t.sequence[MultiArrayDimension] = field(default_factory=list)
    data_offset: t.uint32 = 0


@dataclass
class UInt8MultiArray(IdlStruct, typename="std_msgs::msg::dds_::UInt8MultiArray_"):
    """``std_msgs/msg/UInt8MultiArray``: raw bytes of the serial line, in a recording."""

    layout: MultiArrayLayout = field(default_factory=MultiArrayLayout)
    data: t.sequence[t.uint8] = field(default_factory=list)


#: ``sensor_msgs/msg/BatteryState.POWER_SUPPLY_STATUS_UNKNOWN``.
BATTERY_STATUS_UNKNOWN: Final = 0
#: ``BatteryState.power_supply_technology`` of a :class:`~chassis_sdk.BatteryModel`'s
#: chemistry (``POWER_SUPPLY_TECHNOLOGY_LION`` = 2, ``_LIFE`` = 4); lead-acid has none
#: (``VRLA`` is only the sealed kind), so it stays ``UNKNOWN`` (0), as does a custom curve.
BATTERY_TECHNOLOGY: Final[dict[str, int]] = {"li-ion": 2, "lifepo4": 4}
#: ``diagnostic_msgs/msg/DiagnosticStatus`` levels.
DIAGNOSTIC_OK: Final = 0
DIAGNOSTIC_WARN: Final = 1
DIAGNOSTIC_ERROR: Final = 2
DIAGNOSTIC_STALE: Final = 3

#: The fields that the ``.msg`` files declare ``byte`` (see :data:`_octet`).
_ROS_BYTES: dict[type, frozenset[str]] = {DiagnosticStatus: frozenset({"level"})}

# --- names, definitions and hashes, derived from the fields ----------------------------------


def ros_name(cls: type) -> str:
    """The ROS type name of a message class: ``geometry_msgs/msg/Twist``."""
    idl: str = getattr(cls, "__idl_typename__", "")
    package, kind, dds, base = idl.split("::")
    if dds != "dds_" or not base.endswith("_"):
        raise ValueError(f"{cls!r} is not in ROS 2's DDS shape: {idl!r}")
    return f"{package}/{kind}/{base[:-1]}"


#: REP 2011's field type ids (``type_description_interfaces/msg/FieldType``).
_TYPE_IDS: Final = {
    "int8": 2, "uint8": 3, "int16": 4, "uint16": 5, "int32": 6, "uint32": 7, "int64": 8,
    "uint64": 9, "float32": 10, "float64": 11, "char": 13, "bool": 15, "byte": 16,
    "string": 17,
}  # fmt: skip
_NESTED: Final = 1
_BOUNDED_STRING: Final = 21
_ARRAY, _UNBOUNDED_SEQUENCE = 48, 144


@dataclass(frozen=True)
class _Field:
    name: str
    base: str  # a primitive's name, or a nested type's ROS name
    nested: type | None
    array: int | None  # fixed length
    sequence: bool
    string_capacity: int = 0  # a bounded string's (``string<=N``)

    def description(self) -> dict[str, Any]:
        type_id = _NESTED if self.nested is not None else _TYPE_IDS[self.base]
        if self.string_capacity:
            type_id = _BOUNDED_STRING
        if self.array is not None:
            type_id += _ARRAY
        elif self.sequence:
            type_id += _UNBOUNDED_SEQUENCE
        return {
            "name": self.name,
            "type": {
                "type_id": type_id,
                "capacity": self.array or 0,
                "string_capacity": self.string_capacity,
                "nested_type_name": self.base if self.nested is not None else "",
            },
        }


def _element(hint: Any) -> tuple[str, type | None]:
    """The ROS base type of an annotation that is not an array or a sequence."""
    if hint is bool:
        return "bool", None
    if hint is str:
        return "string", None
    if isinstance(hint, type) and issubclass(hint, IdlStruct):
        return ros_name(hint), hint
    metadata = getattr(hint, "__metadata__", ())
    if metadata and isinstance(metadata[0], str) and metadata[0] in _TYPE_IDS:
        return metadata[0], None
    raise TypeError(f"no ROS type for the annotation {hint!r}")


def _fields(cls: type) -> list[_Field]:
    out = []
    for name, hint in typing.get_type_hints(cls, include_extras=True).items():
        holder = next(iter(getattr(hint, "__metadata__", ())), None)
        kind = type(holder).__name__
        if kind in ("array", "sequence"):
            if kind == "sequence" and getattr(holder, "max_length", None):
                raise TypeError(f"{cls.__name__}.{name}: bounded sequences are not used here")
            base, nested = _element(typing.cast(Any, holder).subtype)
            length = getattr(holder, "length", None) if kind == "array" else None
            out.append(_Field(name, base, nested, length, kind == "sequence"))
        elif kind == "bounded_str":
            capacity = typing.cast(Any, holder).max_length
            out.append(_Field(name, "string", None, None, False, string_capacity=capacity))
        else:
            base, nested = _element(hint)
            if name in _ROS_BYTES.get(cls, ()):
                base = "byte"
            out.append(_Field(name, base, nested, None, False))
    return out


def _closure(cls: type) -> list[type]:
    """``cls`` and every type it uses, depth first in field order, each once."""
    seen: list[type] = []

    def visit(tp: type) -> None:
        if tp in seen:
            return
        seen.append(tp)
        for f in _fields(tp):
            if f.nested is not None:
                visit(f.nested)

    visit(cls)
    return seen


#: rosbag2's patterns (``rosbag2_cpp``'s ``local_message_definition_source.cpp``): a ROS
#: type name, and the type of each field or constant of a ``.msg`` text (a line's first
#: word; a comment line starts with ``#`` and has none).
_TYPE_NAME: Final = re.compile(r"^([a-zA-Z0-9_]+)/(?:msg/|srv/)?([a-zA-Z0-9_]+)$")
_MSG_FIELD_TYPE: Final = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
_PRIMITIVES: Final = frozenset(
    ("bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
     "int32", "uint32", "int64", "uint64", "string")
)  # fmt: skip


def _msg_file(name: str) -> str:
    """The ``.msg`` file of the type ``name`` (``pkg/Type`` or ``pkg/msg/Type``), as
    ROS 2 Jazzy installs it in ``share/pkg/msg/Type.msg``: its text, byte for byte."""
    match = _TYPE_NAME.match(name)
    if match is None:
        raise ValueError(f"not a ROS type name: {name!r}")
    package, base = match.groups()
    path = importlib.resources.files(__package__).joinpath("ros2_msg", package, "msg")
    return path.joinpath(f"{base}.msg").read_text(encoding="utf-8")


def _dependencies(text: str, package: str) -> list[str]:
    """The types a ``.msg`` text uses, as rosbag2 finds them: each line's first word
    that is not a primitive, in its package if it names none, sorted (a ``std::set``)."""
    found = set()
    for match in _MSG_FIELD_TYPE.finditer(text):
        word = match[1]
        if word not in _PRIMITIVES:
            found.add(word if "/" in word else f"{package}/{word}")
    return sorted(found)


def definition(cls: type) -> str:
    """The full message definition of ``cls`` as rosbag2 stores it in a ``ros2msg``
    schema (``LocalMessageDefinitionSource::get_full_text``): its ``.msg`` file as it
    is, then, depth first, each type that file uses (sorted by name, each once) after
    a line break, a line of 80 ``=`` and ``MSG: pkg/Type``."""
    seen: set[str] = set()

    def full_text(name: str) -> str:
        text = _msg_file(name)
        result = text
        for dependency in _dependencies(text, name.split("/", 1)[0]):
            if dependency not in seen:
                seen.add(dependency)
                result += f"\n{'=' * 80}\nMSG: {dependency}\n{full_text(dependency)}"
        return result

    return full_text(ros_name(cls))


def type_hash(cls: type) -> str:
    """The REP 2011 type hash of ``cls`` (``RIHS01_`` and 64 hex digits): the SHA-256 of
    its type description (fields only, referenced types sorted by name) as compact JSON
    with ``", "`` and ``": "`` separators, as ``rosidl`` computes it."""

    def described(tp: type) -> dict[str, Any]:
        fields = [f.description() for f in _fields(tp)]
        return {"type_name": ros_name(tp), "fields": fields}

    referenced = sorted(_closure(cls)[1:], key=ros_name)
    document = {
        "type_description": described(cls),
        "referenced_type_descriptions": [described(tp) for tp in referenced],
    }
    return "RIHS01_" + hashlib.sha256(json.dumps(document).encode()).hexdigest()


def check_namespace(namespace: str) -> str:
    """A ROS namespace, normalised (``robot1`` → ``/robot1``; ``""`` or ``/``: none).

    Raises:
        TypeError: Not a string.
        ValueError: Not a valid ROS name (letters, digits, ``_``, ``/``; no ``//``; a
            token must not start with a digit).
    """
    if not isinstance(namespace, str):
        raise TypeError(f"namespace must be a str, got {type(namespace).__name__}")
    text = namespace.strip()
    if text in ("", "/"):
        return ""
    tokens = text.strip("/").split("/")
    for token in tokens:
        if not token or not token.isascii() or not all(c.isalnum() or c == "_" for c in token):
            raise ValueError(f"namespace must be ROS name tokens (a-z, 0-9, _), got {namespace!r}")
        if token[0].isdigit():
            raise ValueError(f"a namespace token must not start with a digit: {namespace!r}")
    return "/" + "/".join(tokens)


def check_frame(value: str, name: str = "frame") -> str:
    """A tf frame name (``odom``, ``base_link``): a non-empty string without a leading
    ``/`` (tf2 refuses one) or white space.

    Raises:
        TypeError: Not a string.
        ValueError: Empty, with a leading ``/`` or with white space.
    """
    if not isinstance(value, str):
        raise TypeError(f"{name} must be a str, got {type(value).__name__}")
    if not value or value.startswith("/") or any(c.isspace() for c in value):
        raise ValueError(f"{name} must be a tf frame name (no leading '/', no spaces): {value!r}")
    return value


# --- the topics --------------------------------------------------------------------------------

Reliability = Literal["reliable", "best_effort"]
Durability = Literal["volatile", "transient_local"]


@dataclass(frozen=True)
class TopicSpec:
    """A topic the bridge offers (``out``) or reads (``in``), and the recorder writes.

    Attributes:
        name: The ROS name: relative (under the namespace) or absolute (``/tf``).
        type: Its message class.
        direction: ``"out"`` (published) or ``"in"`` (subscribed).
        reliability: ``"reliable"`` or ``"best_effort"``.
        durability: ``"volatile"`` or ``"transient_local"`` (latched, for late joiners).
        depth: The history depth (KEEP_LAST).
    """

    name: str
    type: type
    direction: Literal["in", "out"]
    reliability: Reliability = "reliable"
    durability: Durability = "volatile"
    depth: int = 10

    def qualified(self, namespace: str = "") -> str:
        """The fully qualified ROS name under ``namespace`` (``/robot1/odom``)."""
        if self.name.startswith("/"):
            return self.name
        return f"{namespace.rstrip('/')}/{self.name}" if namespace else f"/{self.name}"

    def dds_topic(self, namespace: str = "") -> str:
        """The DDS topic name (``rt`` and the qualified name: ``rt/robot1/odom``)."""
        return "rt" + self.qualified(namespace)


#: Every topic, by a short key. ``cmd_vel`` is read BEST_EFFORT so that any writer
#: matches (a RELIABLE reader would refuse a BEST_EFFORT one); the rest is RELIABLE, as
#: rclpy's default profile; ``/tf_static`` is latched (TRANSIENT_LOCAL, depth 1), as
#: tf2's static broadcaster.
TOPICS: Final[dict[str, TopicSpec]] = {
    "cmd_vel": TopicSpec("cmd_vel", Twist, "in", "best_effort"),
    "cmd_vel_stamped": TopicSpec("cmd_vel", TwistStamped, "in", "best_effort"),
    "emergency_stop": TopicSpec("emergency_stop", Bool, "in"),
    "odom": TopicSpec("odom", Odometry, "out"),
    "tf": TopicSpec("/tf", TFMessage, "out", depth=100),
    "tf_static": TopicSpec("/tf_static", TFMessage, "out", durability="transient_local", depth=1),
    "battery_state": TopicSpec("battery_state", BatteryState, "out"),
    "diagnostics": TopicSpec("/diagnostics", DiagnosticArray, "out"),
    "imu": TopicSpec("imu/data_raw", Imu, "out"),
    "joint_states": TopicSpec("joint_states", JointState, "out"),
    "robot_description": TopicSpec(
        "robot_description", String, "out", durability="transient_local", depth=1
    ),
}

# --- from the SDK's readings to messages -------------------------------------------------------

#: diff_drive_controller's default covariance diagonals (x, y, z, roll, pitch, yaw). A
#: planar robot knows nothing of z, roll and pitch; robot_localization reads a zero as
#: certainty, so none is zero.
DEFAULT_POSE_COVARIANCE: Final = (0.001, 0.001, 1e6, 1e6, 1e6, 0.01)
DEFAULT_TWIST_COVARIANCE: Final = (0.001, 0.001, 1e6, 1e6, 1e6, 0.01)
_G: Final = 9.80665  # m/s² per g


def covariance(diagonal: Sequence[float], name: str = "covariance") -> list[float]:
    """A 6x6 row-major covariance with ``diagonal`` (six variances) on its diagonal.

    Raises:
        ValueError: Not six finite numbers >= 0, or all of them zero.
    """
    values = [float(v) for v in diagonal]
    if len(values) != 6 or not all(math.isfinite(v) and v >= 0 for v in values):
        raise ValueError(f"{name} must be six finite variances >= 0, got {list(diagonal)!r}")
    if not any(values):
        raise ValueError(f"{name} must not be all zero (a reader takes zero as certainty)")
    matrix = [0.0] * 36
    for i, v in enumerate(values):
        matrix[i * 7] = v
    return matrix


def stamp(epoch: float) -> Time:
    """``builtin_interfaces/Time`` of epoch seconds."""
    ns = round(epoch * 1e9)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _yaw(heading: float) -> Quaternion:
    return Quaternion(z=math.sin(heading / 2.0), w=math.cos(heading / 2.0))


def odometry_message(
    odom: Any,
    epoch: float,
    *,
    frame_id: str = "odom",
    child_frame_id: str = "base_link",
    pose_covariance: Sequence[float] | None = None,
    twist_covariance: Sequence[float] | None = None,
) -> Odometry:
    """``nav_msgs/Odometry`` of a [`Odometry`][chassis_sdk.Odometry] sample.

    Args:
        odom: The sample (``x``, ``y``, ``heading``, ``linear``, ``angular``).
        epoch: Its stamp (wall-clock seconds).
        frame_id: The pose's frame (REP 105: ``odom``).
        child_frame_id: The twist's frame (``base_link``).
        pose_covariance: 36 numbers (see `covariance`); default
            `DEFAULT_POSE_COVARIANCE` on the diagonal.
        twist_covariance: The same for the twist.
    """
    return Odometry(
        header=Header(stamp=stamp(epoch), frame_id=frame_id),
        child_frame_id=child_frame_id,
        pose=PoseWithCovariance(
            pose=Pose(position=Point(x=odom.x, y=odom.y), orientation=_yaw(odom.heading)),
            covariance=list(pose_covariance or covariance(DEFAULT_POSE_COVARIANCE)),
        ),
        twist=TwistWithCovariance(
            twist=Twist(linear=Vector3(x=odom.linear), angular=Vector3(z=odom.angular)),
            covariance=list(twist_covariance or covariance(DEFAULT_TWIST_COVARIANCE)),
        ),
    )


def transform_message(
    odom: Any, epoch: float, *, frame_id: str = "odom", child_frame_id: str = "base_link"
) -> TFMessage:
    """``tf2_msgs/TFMessage`` with the one transform ``frame_id`` → ``child_frame_id``."""
    return TFMessage(
        transforms=[
            TransformStamped(
                header=Header(stamp=stamp(epoch), frame_id=frame_id),
                child_frame_id=child_frame_id,
                transform=Transform(
                    translation=Vector3(x=odom.x, y=odom.y), rotation=_yaw(odom.heading)
                ),
            )
        ]
    )


def battery_message(
    voltage: float,
    epoch: float,
    *,
    frame_id: str = "",
    percentage: float | None = None,
    technology: int = 0,
    design_capacity: float | None = None,
) -> BatteryState:
    """``sensor_msgs/BatteryState`` of a voltage; every field not measured is NaN and the
    status and health are UNKNOWN (0), as the message documents.

    Args:
        voltage: Volts.
        epoch: The stamp (wall-clock seconds).
        frame_id: The header's frame.
        percentage: Charge from 0 to 1, if known (NaN: not known).
        technology: ``POWER_SUPPLY_TECHNOLOGY_*`` (0: unknown).
        design_capacity: Ah, if known (NaN: not known).
    """
    return BatteryState(
        header=Header(stamp=stamp(epoch), frame_id=frame_id),
        voltage=float(voltage),
        percentage=math.nan if percentage is None else float(percentage),
        design_capacity=math.nan if design_capacity is None else float(design_capacity),
        power_supply_status=BATTERY_STATUS_UNKNOWN,
        power_supply_technology=technology,
        present=True,
    )


def charge_message(
    voltage: float, epoch: float, model: BatteryModel | None, *, frame_id: str = ""
) -> BatteryState:
    """`battery_message` with what a [`BatteryModel`][chassis_sdk.BatteryModel] knows: its
    state of charge as ``percentage`` (0..1; NaN while not known, or with no model), its
    chemistry as ``power_supply_technology`` and its capacity as ``design_capacity``.

    ``power_supply_health`` stays UNKNOWN: it is the pack's health (overheat, dead, ...),
    not its charge; a low or critical charge reaches ROS 2 through the percentage and
    ``/diagnostics`` (whose status the device's diagnosis makes a fault then).
    """
    if model is None:
        return battery_message(voltage, epoch, frame_id=frame_id)
    percentage = model.percentage
    default_curve = model.curve == OCV_CURVES.get(model.chemistry)
    return battery_message(
        voltage,
        epoch,
        frame_id=frame_id,
        percentage=None if percentage is None else percentage / 100.0,
        technology=BATTERY_TECHNOLOGY.get(model.chemistry, 0) if default_curve else 0,
        design_capacity=model.capacity_ah,
    )


def imu_message(sample: Any, epoch: float, *, frame_id: str = "imu_link") -> Imu:
    """``sensor_msgs/Imu`` of a board's `ImuSample`:
    acceleration from g to m/s², rates from degrees to radians per second, and no
    orientation (``orientation_covariance[0] = -1``, as the message documents)."""
    accel, gyro = sample.accel, sample.gyro
    unknown = [-1.0] + [0.0] * 8
    return Imu(
        header=Header(stamp=stamp(epoch), frame_id=frame_id),
        orientation=Quaternion(w=0.0),
        orientation_covariance=unknown,
        angular_velocity=Vector3(
            x=math.radians(gyro.x), y=math.radians(gyro.y), z=math.radians(gyro.z)
        ),
        linear_acceleration=Vector3(x=accel.x * _G, y=accel.y * _G, z=accel.z * _G),
    )


def diagnostics_message(
    epoch: float,
    *,
    name: str,
    hardware_id: str,
    level: int,
    message: str,
    values: Iterable[tuple[str, str]] = (),
) -> DiagnosticArray:
    """``diagnostic_msgs/DiagnosticArray`` with one status.

    Args:
        epoch: The stamp (wall-clock seconds).
        name: The status's name (``chassis_sdk: chassis``).
        hardware_id: The device (its port, or its serial number).
        level: `DIAGNOSTIC_OK`, ``WARN``, ``ERROR`` or ``STALE``.
        message: One line.
        values: Key and value pairs (faults, notes, counters).
    """
    status = DiagnosticStatus(
        level=level,
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=[KeyValue(key=k, value=v) for k, v in values],
    )
    return DiagnosticArray(header=Header(stamp=stamp(epoch)), status=[status])


@dataclass(frozen=True)
class StaticTransform:
    """A fixed transform published on ``/tf_static`` (``parent`` → ``child``).

    Attributes:
        parent: The parent frame (``base_link``).
        child: The child frame (``imu_link``).
        x: Offset along the parent's x (m). ``y``, ``z`` likewise.
        yaw: Rotation about the parent's z (rad).
    """

    parent: str
    child: str
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    yaw: float = 0.0

    def message(self, epoch: float) -> TransformStamped:
        half = self.yaw / 2.0
        return TransformStamped(
            header=Header(stamp=stamp(epoch), frame_id=self.parent),
            child_frame_id=self.child,
            transform=Transform(
                translation=Vector3(x=self.x, y=self.y, z=self.z),
                rotation=Quaternion(z=math.sin(half), w=math.cos(half)),
            ),
        )


def static_transforms_message(transforms: Iterable[StaticTransform], epoch: float) -> TFMessage:
    """The ``/tf_static`` message holding ``transforms``, stamped ``epoch``."""
    return TFMessage(transforms=[st.message(epoch) for st in transforms])


# --- a device's readings as messages: one piece for the bridge and the recorder --------------

#: Least seconds between two ``battery_state`` messages from a 50 Hz telemetry stream.
BATTERY_PERIOD: Final = 1.0
#: The longest time between two telemetry readings that the wheels' angles integrate
#: over (s): a longer gap (the link lost) adds nothing rather than a guess.
JOINT_GAP: Final = 0.5


@dataclass(frozen=True)
class Ros2Options:
    """How a device appears in ROS 2: names, frames and covariances, checked when made.
    The live bridge and the rosbag2 recorder take the same options.

    Attributes:
        namespace: Where the relative topics go, normalised (``robot1`` → ``/robot1``;
            ``""``: none).
        frame_id: The odometry frame (REP 105: ``odom``).
        child_frame_id: The robot's frame (``base_link``); also the battery's.
        imu_frame_id: A board's IMU frame (``imu_link``).
        static_transforms: What ``/tf_static`` holds; ``None``: a device with an IMU
            gets ``child_frame_id`` → ``imu_frame_id`` (identity), others none.
        pose_covariance: Six variances (x, y, z, roll, pitch, yaw) for the odometry's
            pose; ``None``: `DEFAULT_POSE_COVARIANCE`.
        twist_covariance: The same for its twist (``None``: `DEFAULT_TWIST_COVARIANCE`).
        tf: Publish odom → base_link on ``/tf`` too (``False`` when an EKF does).
        frame_prefix: Put before every frame name in the messages (`frame`), so that
            several robots share one ``/tf`` tree (robot_state_publisher's
            ``frame_prefix``): ``None`` (the default) is the namespace's, ``/robot1`` →
            ``robot1/`` (``robot1/odom``, ``robot1/base_link``), and none without a
            namespace; ``""``: none.

    Raises:
        TypeError: An option of the wrong type.
        ValueError: A bad namespace, frame, frame prefix, static transform or covariance.
    """

    namespace: str = ""
    frame_id: str = "odom"
    child_frame_id: str = "base_link"
    imu_frame_id: str = "imu_link"
    static_transforms: Sequence[StaticTransform] | None = None
    pose_covariance: Sequence[float] | None = None
    twist_covariance: Sequence[float] | None = None
    tf: bool = True
    frame_prefix: str | None = None

    def __post_init__(self) -> None:
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        put("namespace", check_namespace(self.namespace))
        if self.frame_prefix is None:
            put("frame_prefix", f"{self.namespace.strip('/')}/" if self.namespace else "")
        elif not isinstance(self.frame_prefix, str):
            raise TypeError(f"frame_prefix must be a str, got {type(self.frame_prefix).__name__}")
        elif self.frame_prefix:
            check_frame(self.frame_prefix + "x", "frame_prefix")
        for name in ("frame_id", "child_frame_id", "imu_frame_id"):
            check_frame(getattr(self, name), name)
        if self.static_transforms is not None:
            if isinstance(self.static_transforms, str | bytes) or not isinstance(
                self.static_transforms, Sequence
            ):
                raise TypeError(
                    "static_transforms must be a sequence of StaticTransform, "
                    f"got {type(self.static_transforms).__name__}"
                )
            for st in self.static_transforms:
                if not isinstance(st, StaticTransform):
                    raise TypeError(f"static_transforms must hold StaticTransform, got {st!r}")
                check_frame(st.parent, "a static transform's parent")
                check_frame(st.child, "a static transform's child")
                for axis in ("x", "y", "z", "yaw"):
                    value = getattr(st, axis)
                    if isinstance(value, bool) or not isinstance(value, int | float):
                        raise TypeError(f"a static transform's {axis} must be a number")
                    if not math.isfinite(value):
                        raise ValueError(f"a static transform's {axis} must be finite: {value}")
            put("static_transforms", tuple(self.static_transforms))
        for name in ("pose_covariance", "twist_covariance"):
            value = getattr(self, name)
            if value is not None:
                covariance(value, name)  # raises on a bad one
                put(name, tuple(float(v) for v in value))
        put("tf", bool(self.tf))

    def frame(self, name: str) -> str:
        """A frame's name in the messages: ``name`` after `frame_prefix`."""
        return f"{self.frame_prefix}{name}"

    def static_for(self, streams: Iterable[str]) -> tuple[StaticTransform, ...]:
        """What ``/tf_static`` holds for a device with these streams (prefixed)."""
        if self.static_transforms is not None:
            chosen = tuple(self.static_transforms)
        elif "imu" in streams:
            chosen = (StaticTransform(self.child_frame_id, self.imu_frame_id),)
        else:
            chosen = ()
        return tuple(
            dataclasses.replace(st, parent=self.frame(st.parent), child=self.frame(st.child))
            for st in chosen
        )


class Translator:
    """A device's readings as ROS 2 messages, for the streams it has: which topics (keys
    of `TOPICS`) they give, and the messages of each reading.

    ``odometry`` gives ``odom`` (and ``/tf``), ``imu`` ``imu/data_raw``, ``battery``
    ``battery_state``; without a ``battery`` stream, ``telemetry`` that carries a
    ``voltage`` gives ``battery_state`` at most once per `BATTERY_PERIOD`. With a
    ``geometry``, ``telemetry`` that carries ``wheels`` (each wheel's speed, m/s) gives
    ``joint_states``: each wheel's ``<wheel>_wheel_joint`` speed (rad/s) and angle (rad,
    integrated from the speeds; a gap over `JOINT_GAP` adds nothing).

    With ``forward_only`` (the live bridge), odometry stamps only go forward: a reading
    stamped no later than the last one published (two frames that came in one read
    share its receive time) gives nothing and is counted in `repeated_odometry`. Its
    pose is the one already sent (no time passed), and tf2 would drop it with a
    ``TF_REPEATED_DATA`` warning for each. A recording keeps every reading.

    Args:
        options: The names, frames and covariances.
        streams: The device's stream names (``Notifier.stream_names``).
        battery: The device's ``battery_model`` (``None``: none): ``battery_state``
            then carries its state of charge (see `charge_message`).
        forward_only: Drop odometry stamped no later than the last (see above).
        geometry: The base's size (``None``: no ``joint_states``).

    Raises:
        TypeError: ``battery`` is not a ``BatteryModel`` or ``None``; ``geometry`` not
            a ``Geometry`` or ``None``.
    """

    def __init__(
        self,
        options: Ros2Options,
        streams: Iterable[str],
        *,
        battery: BatteryModel | None = None,
        forward_only: bool = False,
        geometry: Geometry | None = None,
    ) -> None:
        if battery is not None and not isinstance(battery, BatteryModel):
            raise TypeError(f"battery must be a BatteryModel or None, got {battery!r}")
        if geometry is not None and not isinstance(geometry, Geometry):
            raise TypeError(f"geometry must be a Geometry or None, got {geometry!r}")
        self.geometry = geometry
        self._joint_names = (
            [f"{wheel}_wheel_joint" for wheel in geometry.wheels] if geometry else []
        )
        self._angles = [0.0] * len(self._joint_names)
        self._last_joints = -math.inf
        self._telemetry_battery = False
        self.options = options
        #: The state-of-charge estimator read for each ``battery_state``, or ``None``.
        self.battery = battery
        names = set(streams)
        self._pose_cov = covariance(options.pose_covariance or DEFAULT_POSE_COVARIANCE)
        self._twist_cov = covariance(options.twist_covariance or DEFAULT_TWIST_COVARIANCE)
        self._last_battery = -math.inf
        self._last_odometry = -math.inf
        self._forward_only = forward_only
        #: Odometry readings not published: stamped no later than the previous one.
        self.repeated_odometry = 0
        table: dict[str, tuple[tuple[str, ...], Any]] = {}
        if "odometry" in names:
            table["odometry"] = (("odom", "tf") if options.tf else ("odom",), self._odometry)
        if "imu" in names:
            table["imu"] = (("imu",), self._imu)
        if "battery" in names:
            table["battery"] = (("battery_state",), self._battery)
        if "telemetry" in names:
            # The battery from telemetry's voltage, when no battery stream gives it.
            self._telemetry_battery = "battery" not in names
            keys = ("battery_state",) if self._telemetry_battery else ()
            if geometry is not None:
                keys += ("joint_states",)
            if keys:
                table["telemetry"] = (keys, self._telemetry)
        self._table = table
        #: The streams to listen to.
        self.streams: tuple[str, ...] = tuple(table)
        #: The topics (keys of :data:`TOPICS`) the readings give.
        self.topics: tuple[str, ...] = tuple(k for keys, _ in table.values() for k in keys)
        #: What ``/tf_static`` holds (nothing: no such topic).
        self.static: tuple[StaticTransform, ...] = options.static_for(names)

    def messages(self, stream: str, reading: Any) -> list[tuple[str, Any]]:
        """The ``(topic key, message)`` pairs of one reading of ``stream`` (none for a
        stream not in `streams`, or a telemetry frame between two batteries)."""
        entry = self._table.get(stream)
        if entry is None:
            return []
        convert: Any = entry[1]
        out: list[tuple[str, Any]] = convert(reading, wall_time(reading.timestamp))
        return out

    def static_message(self, epoch: float) -> TFMessage:
        """The ``/tf_static`` message, stamped ``epoch``."""
        return static_transforms_message(self.static, epoch)

    def _odometry(self, sample: Any, epoch: float) -> list[tuple[str, Any]]:
        if self._forward_only:
            if sample.timestamp <= self._last_odometry:
                self.repeated_odometry += 1
                return []
            self._last_odometry = sample.timestamp
        o = self.options
        out: list[tuple[str, Any]] = [
            (
                "odom",
                odometry_message(
                    sample,
                    epoch,
                    frame_id=o.frame(o.frame_id),
                    child_frame_id=o.frame(o.child_frame_id),
                    pose_covariance=self._pose_cov,
                    twist_covariance=self._twist_cov,
                ),
            )
        ]
        if o.tf:
            tf = transform_message(
                sample,
                epoch,
                frame_id=o.frame(o.frame_id),
                child_frame_id=o.frame(o.child_frame_id),
            )
            out.append(("tf", tf))
        return out

    def _imu(self, sample: Any, epoch: float) -> list[tuple[str, Any]]:
        frame = self.options.frame(self.options.imu_frame_id)
        return [("imu", imu_message(sample, epoch, frame_id=frame))]

    def _battery(self, reading: Any, epoch: float) -> list[tuple[str, Any]]:
        frame = self.options.frame(self.options.child_frame_id)
        return [
            ("battery_state", charge_message(reading.voltage, epoch, self.battery, frame_id=frame))
        ]

    def _telemetry(self, telemetry: Any, epoch: float) -> list[tuple[str, Any]]:
        out = self._joints(telemetry, epoch) if self.geometry is not None else []
        if not self._telemetry_battery:
            return out
        voltage = getattr(telemetry, "voltage", None)
        at = telemetry.timestamp or time.monotonic()
        if not isinstance(voltage, float) or at - self._last_battery < BATTERY_PERIOD:
            return out
        self._last_battery = at
        return out + self._battery(telemetry, epoch)

    def _joints(self, telemetry: Any, epoch: float) -> list[tuple[str, Any]]:
        geometry = self.geometry
        wheels = getattr(telemetry, "wheels", None)
        if geometry is None or wheels is None:
            return []
        speeds = [getattr(wheels, wheel) / geometry.wheel_radius for wheel in geometry.wheels]
        at = telemetry.timestamp
        dt = at - self._last_joints
        self._last_joints = at
        if 0 < dt <= JOINT_GAP:
            self._angles = [
                math.remainder(a + w * dt, math.tau)
                for a, w in zip(self._angles, speeds, strict=True)
            ]
        message = JointState(
            header=Header(stamp=stamp(epoch)),
            name=list(self._joint_names),
            position=list(self._angles),
            velocity=speeds,
        )
        return [("joint_states", message)]


def _all_types() -> tuple[type, ...]:
    """Every message class here (for the tests and the recorder's schemas)."""
    return tuple(
        obj
        for obj in globals().values()
        if isinstance(obj, type) and issubclass(obj, IdlStruct) and obj is not IdlStruct
    )
