"""Line faults: the damage a noisy line does to what a simulated device sends (noise,
bit flips, lost bytes, late or lost replies), and what it did. Pure: a seeded random
generator, no I/O."""

from __future__ import annotations

import random
from dataclasses import dataclass, field

from ..core.validation import check_probability, check_real

__all__ = ["FaultCounts", "LineFaults", "damage"]


@dataclass(slots=True)
class LineFaults:
    """Damage done to what the simulated device sends, as a noisy line would.

    Rates are probabilities per byte sent (``noise_rate=0.01``: about one junk byte per
    hundred); change them at any time on a running server (``sim.faults.drop_rate =
    0.001``). Host-to-device bytes are not damaged.

    Attributes:
        noise_rate: Chance that a random byte is inserted before each byte.
        bit_flip_rate: Chance that one random bit of a byte is flipped.
        drop_rate: Chance that a byte is lost.
        reply_delay: Seconds each reply to a request is held back.
        reply_loss: Chance that a reply to a request is not sent at all.
        seed: Seed of the fault generator, for repeatable runs.
    """

    noise_rate: float = 0.0
    bit_flip_rate: float = 0.0
    drop_rate: float = 0.0
    reply_delay: float = 0.0
    reply_loss: float = 0.0
    seed: int | None = None
    _rng: random.Random = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("noise_rate", "bit_flip_rate", "drop_rate", "reply_loss"):
            check_probability(getattr(self, name), name)
        check_real(self.reply_delay, "reply_delay", low=0, unit="s")
        self._rng = random.Random(self.seed)

    @property
    def damages_bytes(self) -> bool:
        """True if any per-byte fault is switched on."""
        return bool(self.noise_rate or self.bit_flip_rate or self.drop_rate)


@dataclass(slots=True)
class FaultCounts:
    """What the server's fault injection actually did (for tests to check against)."""

    noise_bytes: int = 0
    flipped_bytes: int = 0
    dropped_bytes: int = 0
    delayed_replies: int = 0
    lost_replies: int = 0


def damage(data: bytes, faults: LineFaults, counts: FaultCounts) -> bytes:
    """Apply ``faults``'s per-byte damage to ``data``, counting it in ``counts``."""
    rng = faults._rng
    rand = rng.random
    noise, flip, drop = faults.noise_rate, faults.bit_flip_rate, faults.drop_rate
    out = bytearray()
    for byte in data:
        if noise and rand() < noise:
            out.append(rng.randrange(256))
            counts.noise_bytes += 1
        if drop and rand() < drop:
            counts.dropped_bytes += 1
            continue
        if flip and rand() < flip:
            byte ^= 1 << rng.randrange(8)
            counts.flipped_bytes += 1
        out.append(byte)
    return bytes(out)
