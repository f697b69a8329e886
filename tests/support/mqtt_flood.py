"""A flood of MQTT 5 PUBLISH packets from its own process, written from the spec (no
MQTT library): the hostile sender of the bridge's tests and ``benchmarks/mqtt_hostile.py``.

``python -m tests.support.mqtt_flood PORT TOPIC --rate 10000 --seconds 2 --kind velocity``
connects to ``127.0.0.1:PORT``, publishes ``rate`` messages a second for ``seconds``
(bounded in count and time: at most ``rate * seconds`` messages, and it gives up
``seconds + 5`` after starting), disconnects cleanly and prints one JSON line::

    {"sent": 20000, "first": 1764612345.1, "last": 1764612347.1, "last_monotonic": 912.3}

``first`` and ``last`` are the wall-clock times the first and last packet were handed
to the kernel, ``last_monotonic`` the last on ``time.monotonic()`` (one clock for every
process of the machine, as the simulators stamp what they receive). Writing the packets by hand keeps the sender cheap (a Python MQTT
client would be the bottleneck at 10,000/s) and independent of the client under test.
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import time

__all__ = ["connect_packet", "main", "payload_for", "publish_packet"]


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        byte, n = n & 0x7F, n >> 7
        out.append(byte | (0x80 if n else 0))
        if not n:
            return bytes(out)


def _string(text: str) -> bytes:
    data = text.encode()
    return len(data).to_bytes(2, "big") + data


def connect_packet(client_id: str) -> bytes:
    """An MQTT 5 CONNECT: clean start, keepalive 60 s, no properties (§3.1)."""
    body = _string("MQTT") + bytes([5, 0x02]) + (60).to_bytes(2, "big") + b"\x00"
    body += _string(client_id)
    return b"\x10" + _varint(len(body)) + body


def publish_packet(topic: str, payload: bytes, *, retain: bool = False) -> bytes:
    """An MQTT 5 PUBLISH at QoS 0 with no properties (§3.3)."""
    body = _string(topic) + b"\x00" + payload
    return bytes([0x30 | int(retain)]) + _varint(len(body)) + body


def payload_for(kind: str, n: int) -> bytes:
    """The ``n``-th payload of a flood of ``kind``: ``velocity`` (valid, 0.3 m/s),
    ``junk`` (not JSON), ``deep`` (nested 100,000 deep), ``bigint`` (5,000 digits)."""
    if kind == "velocity":
        return b'{"linear": 0.3, "angular": 0.0}'
    if kind == "junk":
        return b"junk %d" % n
    if kind == "deep":
        return b"[" * 100_000 + b"]" * 100_000
    if kind == "bigint":
        return b'{"linear": ' + b"9" * 5000 + b', "angular": 0}'
    raise ValueError(f"unknown kind {kind!r}")


def main(argv: list[str] | None = None) -> int:
    """Run one flood; print what was sent as one JSON line."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("port", type=int)
    parser.add_argument("topic")
    parser.add_argument("--rate", type=float, default=10_000.0, help="messages per second")
    parser.add_argument("--seconds", type=float, default=1.0)
    parser.add_argument(
        "--kind", default="velocity", choices=("velocity", "junk", "deep", "bigint")
    )
    args = parser.parse_args(argv)
    total = int(args.rate * args.seconds)
    give_up = time.monotonic() + args.seconds + 5.0
    with socket.create_connection(("127.0.0.1", args.port), timeout=5.0) as sock:
        sock.sendall(connect_packet(f"flood-{time.monotonic_ns()}"))
        if sock.recv(4)[:1] != b"\x20":
            print("no CONNACK", file=sys.stderr)
            return 1
        fixed = args.kind in ("velocity", "deep", "bigint")
        one = publish_packet(args.topic, payload_for(args.kind, 0)) if fixed else b""
        sent, first, last, last_monotonic = 0, 0.0, 0.0, 0.0
        start = time.monotonic()
        while sent < total and time.monotonic() < give_up:
            # Paced in 1 ms batches: the rate holds without a syscall per message.
            due = min(total, int((time.monotonic() - start) * args.rate) + 1)
            if due > sent:
                batch = range(sent, due)
                data = (
                    one * len(batch)
                    if fixed
                    else b"".join(
                        publish_packet(args.topic, payload_for(args.kind, n)) for n in batch
                    )
                )
                sock.sendall(data)
                last, last_monotonic = time.time(), time.monotonic()
                first = first or last
                sent = due
            time.sleep(0.001)
        sock.sendall(b"\xe0\x00")  # DISCONNECT, normal
    print(
        json.dumps({"sent": sent, "first": first, "last": last, "last_monotonic": last_monotonic})
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
