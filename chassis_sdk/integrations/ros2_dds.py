"""The DDS side of the ROS 2 bridge: discovery settings, a participant with ROS 2's
naming and QoS, and readers that wake an asyncio loop.

Why it is shaped this way
-------------------------
ROS 2 is DDS on the wire (RTPS): a node is a participant, a topic ``/odom`` is the DDS
topic ``rt/odom`` of type ``nav_msgs::msg::dds_::Odometry_``, and since Jazzy every
endpoint carries ``typehash=RIHS01_…;`` in its USER_DATA and the participant
``enclave=/;``, as ``rmw`` puts them. Cyclone DDS's Python binding speaks all of it
with no ROS installed.

Cyclone delivers to listeners on its own receive threads. Nothing of the bridge runs
there: a listener only schedules a wake-up on the event loop
(``call_soon_threadsafe``), and the loop ``take()``\\ s what arrived, one sample at a
time, so that a sample that will not decode costs only itself. No thread ever blocks
in a wait set (``take_aiter`` leaves a pool thread blocked when cancelled). Writers
never block either: a reliable writer whose readers lag drops the write at once (it is
counted) rather than stalling the loop for ``max_blocking_time``.

Discovery follows ROS 2's variables (``ROS_DOMAIN_ID``,
``ROS_AUTOMATIC_DISCOVERY_RANGE``, ``ROS_STATIC_PEERS``) as ``rmw_cyclonedds`` does, by
a generated Cyclone configuration; without them, ``CYCLONEDDS_URI`` applies as set.
Static peers come with ``ParticipantIndex auto``: a peer's unicast discovery ports are
then known, and unicast-only discovery takes tens of milliseconds instead of the
seconds of Cyclone's default.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import os
import re
import socket
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Generic, Literal, TypeVar
from xml.sax.saxutils import quoteattr

import anyio
from cyclonedds.core import DDSException, Listener, Policy, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from ..recording.ros2_types import TopicSpec, check_namespace, type_hash

__all__ = [
    "Discovery",
    "Participant",
    "Reader",
    "Writer",
    "check_peer",
    "discovery_from_env",
]

_log = logging.getLogger("chassis_sdk.integrations.ros2")
T = TypeVar("T")

Range = Literal["SUBNET", "LOCALHOST", "OFF", "SYSTEM_DEFAULT"]
_RANGES: tuple[Range, ...] = ("SUBNET", "LOCALHOST", "OFF", "SYSTEM_DEFAULT")
#: The most participants a static-peer configuration looks for on each peer.
_MAX_PARTICIPANT_INDEX = 32
#: Most samples taken per wake-up: a flood cannot hold the loop for long.
_TAKE_BATCH = 256


@dataclass(frozen=True)
class Discovery:
    """How the bridge finds its peers.

    Attributes:
        domain_id: The DDS domain (``ROS_DOMAIN_ID``; 0 to 232).
        range: ``SUBNET`` (multicast, the default), ``LOCALHOST`` (this computer only:
            the loopback interface, no multicast), ``OFF`` (only ``static_peers``), or
            ``SYSTEM_DEFAULT`` (Cyclone's own settings, ``CYCLONEDDS_URI``).
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

    def config(self) -> str | None:
        """The Cyclone DDS configuration for this discovery, or ``None`` to leave
        Cyclone's own (``CYCLONEDDS_URI``, or its defaults)."""
        if self.range == "SYSTEM_DEFAULT" or (self.range == "SUBNET" and not self.static_peers):
            return None
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
        return f'<CycloneDDS><Domain Id="any">{general}{discovery}</Domain></CycloneDDS>'


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


#: The domains this process configured: id -> (configuration, the Domain, its users).
#: Cyclone has one configuration per domain and process, so participants (two bridges
#: for two robots) share one, counted, and a second, different one is refused.
_DOMAINS: dict[int, tuple[str, Domain, int]] = {}


def _acquire_domain(domain_id: int, config: str) -> None:
    held = _DOMAINS.get(domain_id)
    if held is not None:
        if held[0] != config:
            raise ValueError(
                f"DDS domain {domain_id} is already configured otherwise in this process "
                "(one discovery setting per domain: give both bridges the same, or other "
                "domain ids)"
            )
        _DOMAINS[domain_id] = (held[0], held[1], held[2] + 1)
        return
    try:
        domain = Domain(domain_id, config)
    except DDSException as exc:
        raise ValueError(
            f"DDS domain {domain_id} already exists in this process with Cyclone's own "
            "settings (a participant made before the bridge): make the bridge's first, or "
            f"give it Discovery(range='SYSTEM_DEFAULT') and CYCLONEDDS_URI ({exc})"
        ) from None
    _DOMAINS[domain_id] = (config, domain, 1)


def _release_domain(domain_id: int) -> None:
    config, domain, users = _DOMAINS[domain_id]
    if users > 1:
        _DOMAINS[domain_id] = (config, domain, users - 1)
    else:
        del _DOMAINS[domain_id]  # the Domain goes with its last reference


class Participant:
    """One DDS participant: the bridge's node on the graph.

    Args:
        discovery: How to find peers.
        namespace: Where relative topic names go (``/robot1``).

    Raises:
        ValueError: A bad namespace; or the domain is configured otherwise in this
            process already (one discovery setting per domain and process).
        DDSException: Cyclone could not create the participant.
    """

    def __init__(self, discovery: Discovery, namespace: str = "") -> None:
        self.namespace = check_namespace(namespace)
        self.discovery = discovery
        config = discovery.config()
        # A Domain of our own only when the configuration is ours (shared by the
        # participants of this process that ask for the same); it lives as long as they.
        self._domain_id = discovery.domain_id
        self._has_domain = config is not None
        if config is not None:
            _acquire_domain(discovery.domain_id, config)
        try:
            self._participant = DomainParticipant(
                discovery.domain_id, qos=Qos(Policy.Userdata(data=b"enclave=/;"))
            )
        except BaseException:
            if config is not None:
                _release_domain(discovery.domain_id)
            raise
        self._topics: dict[str, Topic[Any]] = {}
        self._entities: list[Any] = []
        self._closed = False

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
        return Writer(dw, spec.qualified(self.namespace))

    def reader(self, spec: TopicSpec, loop: asyncio.AbstractEventLoop) -> Reader[Any]:
        """A reader of ``spec``'s topic that wakes ``loop`` when data or writers change."""
        reader: Reader[Any] = Reader(spec.qualified(self.namespace), loop)
        dr = DataReader(
            self._participant, self._topic(spec), _qos(spec, writer=False), reader.listener()
        )
        reader.attach(dr)
        self._entities.append(dr)
        return reader

    def close(self) -> None:
        """Delete every entity (the readers and writers first: their peers learn at once
        that they are gone), then the participant. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        for entity in reversed([*self._entities, *self._topics.values(), self._participant]):
            with contextlib.suppress(Exception):
                entity.__del__()  # the binding's own delete; garbage collection is late
        self._entities.clear()
        self._topics.clear()
        if self._has_domain:
            self._has_domain = False
            _release_domain(self._domain_id)


class Writer(Generic[T]):
    """A topic's writer; :meth:`write` never blocks and never raises."""

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
    """A topic's reader, for the event loop: :meth:`wait` until something happened,
    :meth:`take` what arrived; :attr:`writers` counts the live writers.

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
        #: Called on the loop when the last writer went away.
        self.on_no_writers: Callable[[], None] | None = None
        #: Called on the loop with the reason when a sample did not decode.
        self.on_undecodable: Callable[[str], None] | None = None
        self._data_pending = False

    def listener(self) -> Listener:
        """The Cyclone listener: on its threads, it only wakes the loop."""
        return Listener(  # type: ignore[no-untyped-call]
            on_data_available=lambda _reader: self._data(),
            on_liveliness_changed=lambda _reader, status: self._wake(int(status.alive_count)),
            on_subscription_matched=lambda _reader, status: self._wake(
                int(status.current_count), matched=True
            ),
        )

    def attach(self, reader: DataReader[T]) -> None:
        self._reader = reader

    def _data(self) -> None:
        # On Cyclone's thread: one wake-up for however many samples arrive before the
        # loop takes them (a flood costs the loop one callback, not one a sample). The
        # loop clears the flag before it sets the event, so a sample that comes after
        # the clear schedules a wake of its own.
        if not self._data_pending:
            self._data_pending = True
            self._wake(None)

    def _wake(self, writers: int | None, *, matched: bool = False) -> None:
        with contextlib.suppress(RuntimeError):  # the loop is closed: nobody listens
            self._loop.call_soon_threadsafe(self._on_loop, writers, matched)

    def _on_loop(self, writers: int | None, matched: bool) -> None:
        if writers is None:
            self._data_pending = False
        else:
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
        """Wake whoever waits in :meth:`wait` (from the loop)."""
        self._event.set()

    async def wait(self) -> None:
        """Until data arrived or the writers changed since the last :meth:`take`."""
        await self._event.wait()

    def take(self) -> Iterator[T]:
        """The valid samples that arrived, oldest first; an undecodable one is counted
        and skipped (it costs only itself); an invalid sample (a writer's unregister
        or dispose) carries no data and is skipped."""
        self._event.clear()
        reader = self._reader
        if reader is None:
            return
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
