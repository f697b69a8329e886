"""The DDS side of the ROS 2 bridge: discovery settings, a participant with ROS 2's
naming and QoS, and readers that wake an asyncio loop.

Why it is shaped this way
-------------------------
ROS 2 is DDS on the wire (RTPS): a node is a participant, a topic ``/odom`` is the DDS
topic ``rt/odom`` of type ``nav_msgs::msg::dds_::Odometry_``, and since Jazzy every
endpoint carries ``typehash=RIHS01_…;`` in its USER_DATA and the participant
``enclave=/;``, as ``rmw`` puts them. Cyclone DDS's Python binding speaks all of it
with no ROS installed.

Cyclone delivers on its own receive threads, and nothing of the bridge runs there: no
reader has a data listener. A Python listener for ``on_data_available`` is entered on
the receive thread for every sample (Cyclone calls it again on each arrival), so a
flood of samples made that thread take the GIL tens of thousands of times a second: a
convoy with the event loop, the receive thread too slow to empty its socket (a
reliable e-stop's DATA lost and resent a heartbeat later) and, on a loaded computer,
the loop held off for up to a second. Instead each reader has a thread of its own,
blocked in a Cyclone wait set (the GIL released) on a read condition: when data is
there it wakes the loop once (``call_soon_threadsafe``) and then waits until the loop
has taken, so it enters Python once per take however many samples arrive. The loop
``take()``\\ s at most a slice of samples per turn, one at a time, so that a sample
that will not decode costs only itself. Closing a reader stops its thread (a guard
condition) before any entity is deleted. Only the rare statuses (writers matched and
alive) are listeners. Writers never block: a reliable writer whose readers lag drops
the write at once (it is counted) rather than stalling the loop for
``max_blocking_time``.

Discovery follows ROS 2's variables (``ROS_DOMAIN_ID``,
``ROS_AUTOMATIC_DISCOVERY_RANGE``, ``ROS_STATIC_PEERS``) as ``rmw_cyclonedds`` does, by
a generated Cyclone configuration, followed by the user's ``CYCLONEDDS_URI`` (which wins
on what it sets). The configuration always lets Fast DDS 3 (ROS 2 Kilted and Lyrical)
and the bridge exchange types with sequences and arrays (`fast_dds_3_compatibility`).
Static peers come with ``ParticipantIndex auto``: a peer's unicast discovery ports are
then known, and unicast-only discovery takes tens of milliseconds instead of the
seconds of Cyclone's default.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import importlib.metadata
import ipaddress
import logging
import math
import os
import re
import socket
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Generic, Literal, TypeVar
from xml.sax.saxutils import quoteattr

import anyio
from cyclonedds.core import (
    DDSException,
    GuardCondition,
    InstanceState,
    Listener,
    Policy,
    Qos,
    ReadCondition,
    SampleState,
    ViewState,
    WaitSet,
)
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from ...recording.ros2_types import TopicSpec, check_namespace, type_hash
from .graph import GRAPH_TOPIC, NODE_NAME, GraphNode, ParticipantEntitiesInfo, check_node_name

__all__ = [
    "Discovery",
    "Participant",
    "Reader",
    "Writer",
    "check_peer",
    "discovery_from_env",
    "fast_dds_3_compatibility",
]

_log = logging.getLogger("chassis_sdk.integrations.ros2")
T = TypeVar("T")

Range = Literal["SUBNET", "LOCALHOST", "OFF", "SYSTEM_DEFAULT"]
_RANGES: tuple[Range, ...] = ("SUBNET", "LOCALHOST", "OFF", "SYSTEM_DEFAULT")
#: The most participants a static-peer configuration looks for on each peer.
_MAX_PARTICIPANT_INDEX = 32
#: Most samples taken per turn of the loop: a flood cannot hold the loop for long
#: (about 2 ms of decoding; more waiting comes back after the others had a turn).
_TAKE_BATCH = 64
#: How long a reader's wake thread waits in Cyclone at most before it looks again
#: whether its reader is closing (a guard condition wakes it at once anyway), in ns.
_WATCH_TIMEOUT_NS = 1_000_000_000
#: Least seconds between two data wake-ups of one reader: a flood is taken at most this
#: often (what comes in between waits in the reader's history, whose depth keeps the
#: newest), so that it costs the loop a bounded share of its time. Traffic slower than
#: this (Nav2's 20 Hz) is woken for at once.
_WAKE_INTERVAL = 0.002


@dataclass(frozen=True)
class Discovery:
    """How the bridge finds its peers.

    Attributes:
        domain_id: The DDS domain (``ROS_DOMAIN_ID``; 0 to 232).
        range: ``SUBNET`` (multicast, the default), ``LOCALHOST`` (this computer only:
            the loopback interface, no multicast), ``OFF`` (only ``static_peers``), or
            ``SYSTEM_DEFAULT`` (Cyclone's own defaults, or ``CYCLONEDDS_URI``'s).
        static_peers: Hosts always contacted by unicast (``ROS_STATIC_PEERS``).

    Raises:
        ValueError: A domain id out of range, an unknown range, or a peer that is not
            a host name or address.
    """

    domain_id: int = 0
    range: Range = "SUBNET"
    static_peers: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if isinstance(self.domain_id, bool) or not isinstance(self.domain_id, int):
            raise TypeError(f"domain_id must be an int, got {self.domain_id!r}")
        if not 0 <= self.domain_id <= 232:
            raise ValueError(f"domain_id must be 0 to 232, got {self.domain_id}")
        if self.range not in _RANGES:
            raise ValueError(f"discovery range must be one of {', '.join(_RANGES)}: {self.range!r}")
        if isinstance(self.static_peers, str) or not isinstance(self.static_peers, tuple | list):
            kind = type(self.static_peers).__name__
            raise TypeError(f"static_peers must be a tuple of host names, got {kind}")
        object.__setattr__(self, "static_peers", tuple(self.static_peers))
        for peer in self.static_peers:
            check_peer(peer)

    async def resolved(self) -> Discovery:
        """This discovery with every static peer a resolved IPv4 address (looked up in a
        thread: the loop never waits on DNS). A name that does not resolve is left out
        with a warning: Cyclone would abort the process on it."""
        if not self.static_peers:
            return self
        found: list[str] = []
        for peer in self.static_peers:
            try:
                found.append(await anyio.to_thread.run_sync(_resolve, peer))
            except OSError as exc:
                _log.warning("static peer %r left out: it does not resolve (%s)", peer, exc)
        return Discovery(self.domain_id, self.range, tuple(dict.fromkeys(found)))

    def config(self, uri: str | None = None) -> str:
        """The Cyclone DDS configuration for this discovery: what Fast DDS 3 needs
        (`fast_dds_3_compatibility`), the discovery ROS 2's variables ask for, then
        ``uri`` (the user's ``CYCLONEDDS_URI``, files or XML, comma-separated), which
        wins on whatever it sets, as with ``rmw_cyclonedds``.

        ``SYSTEM_DEFAULT``, and ``SUBNET`` without static peers, add no discovery
        setting: Cyclone's defaults (multicast on every interface) or ``uri``'s."""
        ours = (
            '<CycloneDDS><Domain Id="any">'
            f"{fast_dds_3_compatibility()}{self._discovery_config()}</Domain></CycloneDDS>"
        )
        return f"{ours},{uri}" if uri else ours

    @property
    def sets_discovery(self) -> bool:
        """Whether the configuration sets discovery (else Cyclone's defaults apply)."""
        return not (
            self.range == "SYSTEM_DEFAULT" or (self.range == "SUBNET" and not self.static_peers)
        )

    def _discovery_config(self) -> str:
        if not self.sets_discovery:
            return ""
        general = ""
        peers = list(self.static_peers)
        if self.range == "LOCALHOST":
            general = (
                '<General><Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>'
                "<AllowMulticast>false</AllowMulticast></General>"
            )
            peers = ["127.0.0.1", *peers]
        elif self.range == "OFF":
            general = "<General><AllowMulticast>false</AllowMulticast></General>"
        entries = "".join(f"<Peer address={quoteattr(p)}/>" for p in dict.fromkeys(peers))
        discovery = (
            "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
            f"<MaxAutoParticipantIndex>{_MAX_PARTICIPANT_INDEX}</MaxAutoParticipantIndex>"
            f"<Peers>{entries}</Peers></Discovery>"
        )
        return general + discovery


#: eProsima's RTPS vendor id, as Cyclone writes it.
_EPROSIMA = "1.15"


def fast_dds_3_compatibility(cyclone_version: str | None = None) -> str:
    """The Cyclone setting that lets Fast DDS 3 (ROS 2 Kilted and Lyrical) and this
    bridge exchange types with a sequence or an array (``Odometry``, ``TFMessage``,
    ``Imu``, ``BatteryState``, ``DiagnosticArray``), or ``""`` where Cyclone has none.

    Both sides send XTypes type information, and they disagree on it: Cyclone's Python
    binding sets ``TRY_CONSTRUCT1`` in the element flags of plain sequences and arrays,
    Fast DDS leaves them 0, so the type hashes differ and each side rejects the other's
    type object ("invalid type object" here, "Inconsistent TypeObject" there): the
    topics match, and no sample of those types is delivered. Cyclone 11 ignores the
    type information of the vendors listed in ``Compatibility/IgnoreTypeInformation``
    and matches by type name, as ROS 2 itself does. Cyclone 0.10 has no such setting.

    Args:
        cyclone_version: The installed ``cyclonedds``'s version (default: looked up).
    """
    if cyclone_version is None:
        cyclone_version = _cyclone_version()
    major = re.match(r"\d+", cyclone_version)
    if major is None or int(major.group()) < 11:
        return ""
    return (
        f"<Compatibility><IgnoreTypeInformation>{_EPROSIMA}</IgnoreTypeInformation></Compatibility>"
    )


@functools.cache
def _warn_old_cyclone() -> None:
    """Once a process: what a Cyclone older than 11 cannot do."""
    _log.warning(
        "cyclonedds %s cannot exchange data with Fast DDS 3 (ROS 2 Kilted, Lyrical); "
        "Fast DDS 2 (Jazzy) and Cyclone peers work. Cyclone 11 works with both (docs/ros2.md)",
        _cyclone_version(),
    )


def _cyclone_version() -> str:
    try:
        return importlib.metadata.version("cyclonedds")
    except importlib.metadata.PackageNotFoundError:
        return "(unknown version)"


_LABEL = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)")


def check_peer(peer: object) -> str:
    """A static peer: an IPv4 address (not unspecified, multicast or broadcast) or a host
    name (RFC 1123 labels).

    Raises:
        TypeError: Not a string.
        ValueError: Anything else (an IPv6 address among them: not supported here).
    """
    if not isinstance(peer, str):
        raise TypeError(f"a static peer must be a str, got {type(peer).__name__}")
    if ":" in peer:
        raise ValueError(f"static peer {peer!r}: IPv6 peers are not supported (give IPv4)")
    try:
        address = ipaddress.IPv4Address(peer)
    except ValueError:
        labels = peer.rstrip(".").split(".")
        if len(peer) > 253 or not all(_LABEL.fullmatch(label) for label in labels):
            raise ValueError(
                f"a static peer must be an IPv4 address or a host name, got {peer!r}"
            ) from None
        if labels[-1].isdigit():
            raise ValueError(
                f"static peer {peer!r} is neither an IPv4 address nor a name"
            ) from None
        return peer
    if address.is_unspecified or address.is_multicast or address == _BROADCAST:
        raise ValueError(f"static peer {peer!r} is not a host's address")
    return peer


_BROADCAST = ipaddress.IPv4Address("255.255.255.255")


def _resolve(peer: str) -> str:
    """``peer``'s first IPv4 address (blocking: run in a thread)."""
    infos = socket.getaddrinfo(peer, None, socket.AF_INET, socket.SOCK_DGRAM)
    return str(infos[0][4][0])


def discovery_from_env(
    env: Mapping[str, str] | None = None,
    *,
    domain_id: int | None = None,
    localhost: bool | None = None,
    static_peers: Sequence[str] | None = None,
) -> Discovery:
    """The discovery ROS 2's variables ask for, with explicit options first.

    Args:
        env: The environment (default ``os.environ``): ``ROS_DOMAIN_ID``,
            ``ROS_AUTOMATIC_DISCOVERY_RANGE``, ``ROS_STATIC_PEERS`` (``;``-separated),
            and the older ``ROS_LOCALHOST_ONLY=1``.
        domain_id: Overrides ``ROS_DOMAIN_ID``.
        localhost: ``True`` overrides the range with ``LOCALHOST``.
        static_peers: Overrides ``ROS_STATIC_PEERS``.

    Raises:
        ValueError: A variable holds something unusable (named in the message).
    """
    env = os.environ if env is None else env
    if domain_id is None:
        raw = env.get("ROS_DOMAIN_ID", "").strip()
        try:
            domain_id = int(raw) if raw else 0
        except ValueError:
            raise ValueError(f"ROS_DOMAIN_ID must be a number, got {raw!r}") from None
    chosen = env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip().upper() or "SUBNET"
    if env.get("ROS_LOCALHOST_ONLY", "").strip() == "1":
        chosen = "LOCALHOST"
    if localhost:
        chosen = "LOCALHOST"
    if chosen not in _RANGES:
        raise ValueError(f"ROS_AUTOMATIC_DISCOVERY_RANGE must be one of {', '.join(_RANGES)}")
    if static_peers is None:
        static_peers = [p.strip() for p in env.get("ROS_STATIC_PEERS", "").split(";") if p.strip()]
    return Discovery(domain_id, chosen, tuple(static_peers))


def _qos(spec: TopicSpec, *, writer: bool) -> Qos:
    reliability = (
        # A writer never blocks the loop: a full history drops the write at once.
        Policy.Reliability.Reliable(max_blocking_time=0)
        if spec.reliability == "reliable"
        else Policy.Reliability.BestEffort
    )
    durability = (
        Policy.Durability.TransientLocal
        if spec.durability == "transient_local"
        else Policy.Durability.Volatile
    )
    policies: list[Any] = [
        reliability,
        durability,
        Policy.History.KeepLast(spec.depth),
        Policy.Userdata(data=f"typehash={type_hash(spec.type)};".encode()),
    ]
    if writer:
        # Plain CDR (XCDR1), what ROS 2's middlewares write and read.
        policies.append(Policy.DataRepresentation(use_cdrv0_representation=True))
    return Qos(*policies)


#: ``ros_discovery_info``'s QoS, as ``rmw`` sets it: reliable, transient local, the last
#: message only (a late reader gets it), plain CDR.
_GRAPH_QOS = Qos(
    Policy.Reliability.Reliable(max_blocking_time=0),
    Policy.Durability.TransientLocal,
    Policy.History.KeepLast(1),
    Policy.Userdata(data=f"typehash={type_hash(ParticipantEntitiesInfo)};".encode()),
    Policy.DataRepresentation(use_cdrv0_representation=True),
)


#: The domains this process configured: id -> (configuration, the Domain, its users).
#: Cyclone has one configuration per domain and process, so participants (two bridges
#: for two robots) share one, counted, and a second, different one is refused.
_DOMAINS: dict[int, tuple[str, Domain, int]] = {}


def _acquire_domain(domain_id: int, config: str, *, required: bool) -> bool:
    """Configure ``domain_id`` with ``config`` for this process (or share the same
    configuration); False when a participant made before the bridge holds the domain
    with Cyclone's own settings and the bridge can do with them (not ``required``)."""
    held = _DOMAINS.get(domain_id)
    if held is not None:
        if held[0] != config:
            raise ValueError(
                f"DDS domain {domain_id} is already configured otherwise in this process "
                "(one discovery setting per domain: give both bridges the same, or other "
                "domain ids)"
            )
        _DOMAINS[domain_id] = (held[0], held[1], held[2] + 1)
        return True
    try:
        domain = Domain(domain_id, config)
    except DDSException as exc:
        if required:
            raise ValueError(
                f"DDS domain {domain_id} already exists in this process with Cyclone's own "
                "settings (a participant made before the bridge): make the bridge's first, "
                f"or use another domain id ({exc})"
            ) from None
        _log.warning(
            "DDS domain %d already exists in this process with Cyclone's own settings (a "
            "participant made before the bridge): the bridge uses them, and Fast DDS 3 "
            "peers (ROS 2 Kilted, Lyrical) will not get its odometry; make the bridge's "
            "participant first",
            domain_id,
        )
        return False
    _DOMAINS[domain_id] = (config, domain, 1)
    return True


def _release_domain(domain_id: int) -> None:
    config, domain, users = _DOMAINS[domain_id]
    if users > 1:
        _DOMAINS[domain_id] = (config, domain, users - 1)
    else:
        del _DOMAINS[domain_id]  # the Domain goes with its last reference


class Participant:
    """One DDS participant: the bridge's node on the graph.

    It publishes the node on ``ros_discovery_info`` (see `graph`) each time it makes a
    reader or a writer, so ``ros2 node list`` shows ``node_name`` under ``namespace``
    and ``ros2 node info`` its topics.

    Args:
        discovery: How to find peers.
        namespace: Where relative topic names go (``/robot1``).
        node_name: The node's name on the graph.

    Raises:
        TypeError: A namespace or node name that is not a string.
        ValueError: A bad namespace or node name; or the domain is configured otherwise
            in this process already (one discovery setting per domain and process).
        DDSException: Cyclone could not create the participant.
    """

    def __init__(
        self, discovery: Discovery, namespace: str = "", node_name: str = NODE_NAME
    ) -> None:
        self.namespace = check_namespace(namespace)
        self.node_name = check_node_name(node_name)
        self.discovery = discovery
        config = discovery.config(os.environ.get("CYCLONEDDS_URI"))
        if not fast_dds_3_compatibility():
            _warn_old_cyclone()
        # A Domain of our own (shared by the participants of this process that ask for
        # the same configuration); it lives as long as they.
        self._domain_id = discovery.domain_id
        self._has_domain = _acquire_domain(
            discovery.domain_id, config, required=discovery.sets_discovery
        )
        try:
            self._participant = DomainParticipant(
                discovery.domain_id, qos=Qos(Policy.Userdata(data=b"enclave=/;"))
            )
        except BaseException:
            if self._has_domain:
                _release_domain(discovery.domain_id)
            raise
        self._topics: dict[str, Topic[Any]] = {}
        self._entities: list[Any] = []
        self._readers: list[Reader[Any]] = []
        self._closed = False
        #: The node and its endpoints, as ``ros_discovery_info`` tells the graph.
        self.node = GraphNode(self._participant.guid.bytes, self.namespace, self.node_name)
        graph_topic = self._topics[GRAPH_TOPIC] = Topic(
            self._participant, GRAPH_TOPIC, ParticipantEntitiesInfo
        )
        self._graph = DataWriter(self._participant, graph_topic, _GRAPH_QOS)
        self._announce()

    def _announce(self, *, present: bool = True) -> None:
        with contextlib.suppress(DDSException):  # never blocks (keep last 1)
            self._graph.write(self.node.message(present=present))

    def _topic(self, spec: TopicSpec) -> Topic[Any]:
        name = spec.dds_topic(self.namespace)
        topic = self._topics.get(name)
        if topic is None:
            topic = self._topics[name] = Topic(self._participant, name, spec.type)
        return topic

    def writer(self, spec: TopicSpec) -> Writer[Any]:
        """A writer of ``spec``'s topic, with its QoS."""
        dw = DataWriter(self._participant, self._topic(spec), _qos(spec, writer=True))
        self._entities.append(dw)
        self.node.writers.append(dw.guid.bytes)
        self._announce()
        return Writer(dw, spec.qualified(self.namespace))

    def reader(self, spec: TopicSpec, loop: asyncio.AbstractEventLoop) -> Reader[Any]:
        """A reader of ``spec``'s topic that wakes ``loop`` when data or writers change."""
        reader: Reader[Any] = Reader(spec.qualified(self.namespace), loop)
        dr = DataReader(
            self._participant, self._topic(spec), _qos(spec, writer=False), reader.listener()
        )
        self._entities.append(dr)
        self._readers.append(reader)
        self.node.readers.append(dr.guid.bytes)
        self._announce()
        reader.attach(dr, self._participant)
        return reader

    def close(self) -> None:
        """Delete every entity (the readers and writers first: their peers learn at once
        that they are gone), then the participant. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._announce(present=False)  # the node goes before its endpoints
        for reader in self._readers:  # their threads out of Cyclone's waits first
            reader.close()
        self._readers.clear()
        entities = [self._graph, *self._entities, *self._topics.values(), self._participant]
        for entity in reversed(entities):
            with contextlib.suppress(Exception):
                entity.__del__()  # the binding's own delete; garbage collection is late
        self._entities.clear()
        self._topics.clear()
        if self._has_domain:
            self._has_domain = False
            _release_domain(self._domain_id)


class Writer(Generic[T]):
    """A topic's writer; `write` never blocks and never raises."""

    def __init__(self, writer: DataWriter[T], name: str) -> None:
        self._writer = writer
        self.name = name
        #: Samples written, and writes dropped (a reader lagging, a DDS error).
        self.written = 0
        self.dropped = 0

    def write(self, sample: T) -> bool:
        """Write ``sample``; ``False`` (counted) when DDS did not take it."""
        try:
            self._writer.write(sample)
        except DDSException as exc:
            self.dropped += 1
            if self.dropped == 1 or self.dropped % 1000 == 0:
                _log.warning("%s: write dropped (%s; %d so far)", self.name, exc, self.dropped)
            return False
        self.written += 1
        return True


class Reader(Generic[T]):
    """A topic's reader, for the event loop: `wait` until something happened,
    `take` what arrived; `writers` counts the live writers.

    Data wakes the loop from a thread of the reader's own (started by `attach`,
    stopped by `close`), blocked in a Cyclone wait set: once per take, never once
    per sample (see the module's docstring).

    Args:
        name: The topic's ROS name (for the log).
        loop: The loop to wake.
    """

    def __init__(self, name: str, loop: asyncio.AbstractEventLoop) -> None:
        self.name = name
        self._loop = loop
        self._event = asyncio.Event()
        self._reader: DataReader[T] | None = None
        #: Live writers matched now (the liveliness and the subscription-matched status).
        self.writers = 0
        self._alive = self._matched = 0
        self._armed = False  # a writer came since the last "no writer left"
        #: Samples that did not decode (refused, never acted on).
        self.undecodable = 0
        #: Times the wake thread woke the loop for data (at most one per take).
        self.data_wakes = 0
        #: Called on the loop when the last writer went away.
        self.on_no_writers: Callable[[], None] | None = None
        #: Called on the loop with the reason when a sample did not decode.
        self.on_undecodable: Callable[[str], None] | None = None
        # The wake thread's: set by the loop when it has taken (or the reader closes).
        self._taken = threading.Event()
        self._closing = False
        self._thread: threading.Thread | None = None
        self._waitset: WaitSet | None = None
        self._condition: ReadCondition | None = None
        self._guard: GuardCondition | None = None

    def listener(self) -> Listener:
        """The Cyclone listener, for the writers' statuses only (rare; on Cyclone's
        threads it only wakes the loop). There is no data callback: see `attach`."""
        return Listener(  # type: ignore[no-untyped-call]
            on_liveliness_changed=lambda _reader, status: self._wake(int(status.alive_count)),
            on_subscription_matched=lambda _reader, status: self._wake(
                int(status.current_count), matched=True
            ),
        )

    def attach(self, reader: DataReader[T], participant: DomainParticipant | None = None) -> None:
        """Read from ``reader``; with ``participant`` (the reader's), start the thread
        that wakes the loop when data is there.

        Raises:
            DDSException: Cyclone could not make the wait set or its conditions.
        """
        self._reader = reader
        if participant is None:
            return
        mask = SampleState.Any | ViewState.Any | InstanceState.Any
        self._condition = ReadCondition(reader, mask)
        self._guard = GuardCondition(participant)
        self._waitset = WaitSet(participant)
        self._waitset.attach(self._condition)
        self._waitset.attach(self._guard)
        self._thread = threading.Thread(
            target=self._watch, args=(self._waitset,), name=f"dds {self.name}", daemon=True
        )
        self._thread.start()

    def _watch(self, waitset: WaitSet) -> None:
        # On the reader's own thread. The wait is in C with the GIL released; the read
        # condition holds while any sample is in the reader, so after one wake this
        # waits for the loop's take before it looks again: one wake (one entry into
        # Python here) per take, however fast samples come.
        woke = -math.inf
        while not self._closing:
            try:
                triggered = waitset.wait(_WATCH_TIMEOUT_NS)
            except DDSException as exc:  # the wait set went: nothing more to watch
                if not self._closing:
                    _log.warning("%s: the data wake-up ended (%s)", self.name, exc)
                return
            if self._closing:
                return
            if not triggered:
                continue  # a timeout (the guard is only set when closing)
            rest = woke + _WAKE_INTERVAL - time.monotonic()
            if rest > 0:
                time.sleep(rest)  # a flood: let it gather in the history a moment
            self._taken.clear()
            self.data_wakes += 1
            woke = time.monotonic()
            self._wake(None)
            self._taken.wait()

    def close(self) -> None:
        """Stop the wake thread (before the reader is deleted) and delete its wait set
        and conditions. Safe to call twice; the reader itself is the participant's."""
        self._closing = True
        self._taken.set()
        guard, thread = self._guard, self._thread
        if guard is not None:
            with contextlib.suppress(DDSException):
                guard.set(True)
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2 * _WATCH_TIMEOUT_NS / 1e9)
            if thread.is_alive():
                _log.warning("%s: the data wake-up thread did not stop", self.name)
                return  # its wait set is left to the participant's deletion
        self._thread = None
        for entity in (self._waitset, self._condition, self._guard):
            if entity is not None:
                with contextlib.suppress(Exception):
                    entity.__del__()  # the binding's own delete
        if self._waitset is not None:
            self._waitset.attached = []
        self._waitset = self._condition = self._guard = None

    def _wake(self, writers: int | None, *, matched: bool = False) -> None:
        with contextlib.suppress(RuntimeError):  # the loop is closed: nobody listens
            self._loop.call_soon_threadsafe(self._on_loop, writers, matched)

    def _on_loop(self, writers: int | None, matched: bool) -> None:
        if writers is not None:
            # Matched counts every writer, liveliness the live ones: either falling to
            # zero means nobody is left to command (each is watched on its own, so one
            # status that never comes cannot hide the other), and it is told once: the
            # other falling after it is the same leaving. A count that rises arms it.
            before = self._matched if matched else self._alive
            if matched:
                self._matched = writers
            else:
                self._alive = writers
            self.writers = min(self._alive, self._matched)
            if writers > before:
                self._armed = True
            elif before > 0 and writers == 0 and self._armed:
                self._armed = False
                if self.on_no_writers is not None:
                    self.on_no_writers()
        self._event.set()

    def wake(self) -> None:
        """Wake whoever waits in `wait` (from the loop)."""
        self._event.set()

    async def wait(self) -> None:
        """Until data arrived or the writers changed since the last `take`."""
        await self._event.wait()

    def take(self) -> Iterator[T]:
        """The valid samples that arrived, oldest first, at most a slice of them (more
        waiting sets the event again: the caller comes back after yielding); an
        undecodable one is counted and skipped (it costs only itself); an invalid
        sample (a writer's unregister or dispose) carries no data and is skipped."""
        self._event.clear()
        reader = self._reader
        if reader is None:
            return
        try:
            for _ in range(_TAKE_BATCH):
                try:
                    got = reader.take(N=1)
                except Exception as exc:  # bytes that are not this type: refused
                    self.undecodable += 1
                    if self.on_undecodable is not None:
                        self.on_undecodable(f"a sample did not decode ({type(exc).__name__})")
                    else:
                        _log.debug("%s: a sample did not decode (%r)", self.name, exc)
                    continue
                if not got:
                    return
                sample = got[0]
                info = getattr(sample, "sample_info", None)
                if (
                    info is not None
                    and getattr(info, "valid_data", True)
                    and hasattr(sample, "__idl_typename__")
                ):
                    yield sample
            self._event.set()  # more may be waiting: come back after the others had a turn
        finally:
            self._taken.set()  # the wake thread may look again
