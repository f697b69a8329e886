"""The bridge's node on the ROS 2 graph (``ros_discovery_info``): the types' hashes and
bytes as ROS 2 has them, and the node name's rules. Against a Fast DDS peer:
``test_ros2_interop.py::test_ros_discovery_info_names_the_node_and_exactly_the_endpoints_peers_discover``.
"""

from __future__ import annotations

import struct
from typing import cast

import pytest

from chassis_sdk.integrations.ros2.graph import (
    Gid,
    GraphNode,
    NodeEntitiesInfo,
    ParticipantEntitiesInfo,
    check_node_name,
)
from chassis_sdk.recording.ros2_types import type_hash

pytestmark = pytest.mark.codec


@pytest.mark.parametrize(
    ("cls", "expected"),
    [
        # From rosidl's generated rmw_dds_common/msg/detail/*__description.c (Jazzy):
        # `char[16]` is an IDL uint8 array, the names are `string<=256`. (rosbags' type
        # store has `char` there and so another hash, e725f4a5…: not what ROS sends.)
        (Gid, "RIHS01_ab6f21cfbb0a6dbb837161e1110c2051a2850ed9f9c53944d7115d9bcebedf71"),
        (
            NodeEntitiesInfo,
            "RIHS01_8ffef65ee2d088c63b1e8fcd31e800ba9fc8dbe0ee15ca60d1676de5218087a7",
        ),
        (
            ParticipantEntitiesInfo,
            "RIHS01_91a0593bacdcc50ea9bdcf849a938b128412cc1ea821245c663bcd26f83c295e",
        ),
    ],
)
def test_the_graph_types_hash_as_ros_2_generates_them(cls: type, expected: str) -> None:
    assert type_hash(cls) == expected


def _cdr_string(text: str) -> bytes:
    raw = text.encode() + b"\0"
    return struct.pack("<I", len(raw)) + raw + bytes(-len(raw) % 4)


def test_the_message_is_plain_cdr_in_rmw_dds_commons_layout() -> None:
    participant, reader, writer = bytes(range(16)), bytes([1] * 16), bytes([2] * 16)
    node = GraphNode(participant, "/robot1", "chassis_bridge", [reader], [writer])
    expected = (
        b"\x00\x01\x00\x00"  # CDR, little endian
        + participant
        + struct.pack("<I", 1)  # one node
        + _cdr_string("/robot1")
        + _cdr_string("chassis_bridge")
        + struct.pack("<I", 1)
        + reader
        + struct.pack("<I", 1)
        + writer
    )
    assert node.message().serialize() == expected
    # The node going: the participant with no node.
    gone = participant + struct.pack("<I", 0)
    assert node.message(present=False).serialize() == b"\x00\x01\x00\x00" + gone


def test_no_namespace_is_sent_as_the_root() -> None:
    message = GraphNode(bytes(16), "", "chassis_bridge").message()
    (info,) = cast(list[NodeEntitiesInfo], message.node_entities_info_seq)
    assert (str(info.node_namespace), str(info.node_name)) == ("/", "chassis_bridge")


@pytest.mark.parametrize(
    ("name", "error"),
    [
        ("chassis_bridge", None),
        ("r2", None),
        ("", ValueError),
        ("2robot", ValueError),
        ("my-node", ValueError),
        ("a/b", ValueError),
        ("n" * 256, ValueError),
        ("bridge\u00e9", ValueError),
        (5, TypeError),
    ],
)
def test_node_names_follow_ros_rules(name: object, error: type[Exception] | None) -> None:
    if error is None:
        assert check_node_name(name) == name  # type: ignore[arg-type]
    else:
        with pytest.raises(error):
            check_node_name(name)  # type: ignore[arg-type]


def test_a_gid_is_sixteen_bytes() -> None:
    with pytest.raises(ValueError, match="16 bytes"):
        Gid.of(bytes(12))
