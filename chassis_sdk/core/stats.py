"""``LinkStats``: a device's link counters, as one snapshot value."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .framing import DecoderStats

__all__ = ["LinkStats"]


@dataclass(frozen=True, slots=True)
class LinkStats:
    """A snapshot of a device's link counters (cumulative over reconnects).

    Attributes:
        bytes_received: Bytes read from the port.
        bytes_sent: Bytes written to the port.
        frames: Frames decoded.
        frames_sent: Frames written.
        bytes_dropped: Received bytes skipped as noise.
        checksum_errors: Received candidate frames with a bad check.
        malformed_frames: Frames that checked out but carried invalid content.
        length_mismatches: Frames accepted despite a wrong length byte.
        misaligned_frames: Frames that passed the check but were refused because the
            bytes after them showed them shifted by line noise (codecs with an alignment rule).
        unmatched_replies: Replies nobody was waiting for.
        late_replies: Replies to requests that had already timed out: dropped, never
            given to a later call (see "Requests" in the README).
        frames_discarded: Frames not sent because the device was not reading: velocity
            frames replaced by newer ones or expired while they waited, frames over the
            bound of what may wait, and what was still waiting at close.
        queue_drops: Messages dropped because a subscriber fell behind.
        sequence_gaps: Breaks in the device's frame numbers (protocols that number
            frames), whether it keeps one counter for every frame or one per frame id (detected; see
            ``Chassis.sequence_scheme``). Counted within each connection: the break
            a reconnect makes is not a gap.
        reconnects: Successful reconnects.
        resends: Velocity frames re-sent by the watchdog.
        command_expiries: Velocity commands zeroed by the deadman or ``duration``.
    """

    bytes_received: int = 0
    bytes_sent: int = 0
    frames: int = 0
    frames_sent: int = 0
    bytes_dropped: int = 0
    checksum_errors: int = 0
    malformed_frames: int = 0
    length_mismatches: int = 0
    misaligned_frames: int = 0
    unmatched_replies: int = 0
    late_replies: int = 0
    frames_discarded: int = 0
    queue_drops: int = 0
    sequence_gaps: int = 0
    reconnects: int = 0
    resends: int = 0
    command_expiries: int = 0

    @classmethod
    def of(cls, decoded: DecoderStats, **rest: int) -> LinkStats:
        """The counters of a device: its decoder's (bytes received, frames, bytes
        dropped, checksum errors, malformed, length mismatches, misaligned), and
        ``rest`` by name (the writer's, the requests', the streams', ...)."""
        return cls(
            bytes_received=decoded.bytes_received,
            frames=decoded.frames,
            bytes_dropped=decoded.bytes_dropped,
            checksum_errors=decoded.checksum_errors,
            malformed_frames=decoded.malformed_frames,
            length_mismatches=decoded.length_mismatches,
            misaligned_frames=decoded.misaligned_frames,
            **rest,
        )

    def __str__(self) -> str:
        """The counters that are not zero, ``name=value`` each (``frames=55
        frames_sent=4 ...``), or ``no traffic``."""
        return " ".join(f"{k}={v}" for k, v in self.as_dict().items() if v) or "no traffic"

    def as_dict(self) -> dict[str, int]:
        """Return the counters as a plain ``dict``."""
        return {f.name: getattr(self, f.name) for f in fields(self)}
