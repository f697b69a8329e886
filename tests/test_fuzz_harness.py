"""The fuzz harness's checks (fuzz/harness.py), run on its seeds and on seeded random
mutations of them, so the checks themselves are exercised on every test run; atheris
drives the same checks coverage-guided in CI (see README)."""

from __future__ import annotations

import random

import pytest

from .support.fuzz import harness, mutate

pytestmark = pytest.mark.codec


@pytest.mark.parametrize("target", sorted(harness.targets()))
def test_seeds_are_valid_frames(target: str) -> None:
    factory, _ = harness.targets()[target]
    for seed in harness.seeds(target):
        assert factory().feed(seed[1:]), f"seed {seed.hex()} decodes to nothing"


@pytest.mark.parametrize("target", sorted(harness.targets()))
def test_checks_hold_on_seeds_and_mutations(target: str) -> None:
    rng = random.Random(target)
    seeds = harness.seeds(target)
    for seed in seeds:
        harness.check(target, seed)
    for _ in range(300):
        harness.check(target, mutate(rng, rng.choice(seeds)))


def test_a_split_dependent_decoder_would_be_caught(monkeypatch: pytest.MonkeyPatch) -> None:
    class Forgetful:
        """Drops whatever one feed() cannot finish: its output depends on the split."""

        def __init__(self) -> None:
            self.inner = harness.targets()["chassis"][0]()

        def feed(self, data: bytes) -> list[object]:
            out: list[object] = self.inner.feed(data)
            self.inner.reset()
            return out

        @property
        def stats(self) -> object:
            return self.inner.stats

        @property
        def buffered(self) -> int:
            return int(self.inner.buffered)

    real = harness.targets
    monkeypatch.setattr(harness, "targets", lambda: {**real(), "forgetful": (Forgetful, 256)})
    with pytest.raises(AssertionError):
        harness.check("forgetful", harness.seeds("chassis")[0])
