"""The bridge as a node of the ROS 2 graph: what ``ros2 node list`` and ``ros2 node
info`` read.

ROS 2's tools learn which nodes exist from one DDS topic only, ``ros_discovery_info``
(no ``rt/`` prefix): each process's ``rmw`` publishes there, for its participant, a
``rmw_dds_common/msg/ParticipantEntitiesInfo``: the participant's GID and, for each of
its nodes, the namespace, the name and the GIDs of the node's readers and writers (a
GID is the entity's 16-byte DDS GUID). ``ros2 node list`` lists the names;
``ros2 node info`` maps the endpoints it discovered to nodes by those GIDs. Topics
alone (``ros2 topic list``) come from DDS discovery and need none of this.

The message is sent whole on every change, RELIABLE, TRANSIENT_LOCAL and KEEP_LAST 1
(a late ``ros2`` daemon gets the last one), as ``rmw_cyclonedds`` and ``rmw_fastrtps``
do. Its ``gid`` is the participant's own GUID: when the participant leaves DDS
discovery, the tools drop its nodes with it.
"""

# No ``from __future__ import annotations``: Cyclone reads the field annotations as types.
from dataclasses import dataclass, field
from typing import Final

from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t

__all__ = [
    "GRAPH_TOPIC",
    "NODE_NAME",
    "Gid",
    "GraphNode",
    "NodeEntitiesInfo",
    "ParticipantEntitiesInfo",
    "check_node_name",
]

#: The DDS topic of the graph (``rmw``'s, outside ROS's ``rt/`` names).
GRAPH_TOPIC: Final = "ros_discovery_info"
#: The bridge's node name (``ros2 node list``: ``/chassis_bridge``, or
#: ``/robot1/chassis_bridge`` under a namespace).
NODE_NAME: Final = "chassis_bridge"
#: ``rmw_dds_common``'s bound on a node's name and namespace.
_NAME_CAPACITY: Final = 256


@dataclass
class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
    """``rmw_dds_common/msg/Gid``: an entity's 16-byte GUID (``char[16]`` in the
    ``.msg``, an octet array on the wire)."""

    data: t.array[t.uint8, 16] = field(default_factory=lambda: [0] * 16)

    @classmethod
    def of(cls, guid: bytes) -> "Gid":
        """The GID of a 16-byte GUID (``entity.guid.bytes``)."""
        if len(guid) != 16:
            raise ValueError(f"a GUID is 16 bytes, got {len(guid)}")
        return cls(data=list(guid))


@dataclass
class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
    """``rmw_dds_common/msg/NodeEntitiesInfo``: one node and its endpoints."""

    node_namespace: t.bounded_str[256] = ""
    node_name: t.bounded_str[256] = ""
    reader_gid_seq: t.sequence[Gid] = field(default_factory=list)
    writer_gid_seq: t.sequence[Gid] = field(default_factory=list)


@dataclass
class ParticipantEntitiesInfo(
    IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"
):
    """``rmw_dds_common/msg/ParticipantEntitiesInfo``: a participant's nodes."""

    gid: Gid = field(default_factory=Gid)
    node_entities_info_seq: t.sequence[NodeEntitiesInfo] = field(default_factory=list)


def check_node_name(name: str) -> str:
    """A ROS node name: letters, digits and ``_``, not starting with a digit.

    Raises:
        TypeError: Not a string.
        ValueError: Not a valid node name.
    """
    if not isinstance(name, str):
        raise TypeError(f"node name must be a str, got {type(name).__name__}")
    if (
        not name
        or len(name) >= _NAME_CAPACITY
        or not name.isascii()
        or not all(c.isalnum() or c == "_" for c in name)
        or name[0].isdigit()
    ):
        raise ValueError(
            f"node name must be a-z, A-Z, 0-9 and _, not starting with a digit: {name!r}"
        )
    return name


@dataclass
class GraphNode:
    """One node of a participant, and the GUIDs of its endpoints as they are made.

    Attributes:
        participant: The participant's 16-byte GUID.
        namespace: The node's namespace (``""``: none, sent as ``/``).
        name: The node's name.
        readers: Its readers' GUIDs.
        writers: Its writers' GUIDs.
    """

    participant: bytes
    namespace: str
    name: str
    readers: list[bytes] = field(default_factory=list)
    writers: list[bytes] = field(default_factory=list)

    def message(self, *, present: bool = True) -> ParticipantEntitiesInfo:
        """What ``ros_discovery_info`` carries for the participant: this node, or (not
        ``present``, the node going) none."""
        nodes = []
        if present:
            nodes.append(
                NodeEntitiesInfo(
                    node_namespace=self.namespace or "/",
                    node_name=self.name,
                    reader_gid_seq=[Gid.of(g) for g in self.readers],
                    writer_gid_seq=[Gid.of(g) for g in self.writers],
                )
            )
        return ParticipantEntitiesInfo(gid=Gid.of(self.participant), node_entities_info_seq=nodes)
