"""A real headless Chromium for the dashboard's tests: Debian's ``chromium`` driven by
Playwright (``executable_path``: no browser download), with the flags this machine's
closed network needs (no background connections, no QUIC, no first-run work)."""

from __future__ import annotations

import io
import os
import shutil
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from .watch import needs

#: Where Debian puts it; ``CHASSIS_SDK_CHROMIUM`` names another.
CHROMIUM = os.environ.get("CHASSIS_SDK_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
FLAGS = [
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
]


@asynccontextmanager
async def chromium() -> AsyncIterator[Any]:
    """A launched headless browser. A machine without Chromium fails the test (CI
    installs it: ``sh tools/system-deps.sh``), it does not skip it."""
    from playwright.async_api import async_playwright

    needs("browser", "launches Chromium")
    assert os.path.exists(CHROMIUM), (
        f"no Chromium at {CHROMIUM}: run `sh tools/system-deps.sh` (Debian's chromium)"
    )
    async with async_playwright() as pw:
        browser = await pw.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        try:
            yield browser
        finally:
            await browser.close()


def is_blank(png: bytes) -> bool:
    """Whether a screenshot shows (next to) nothing: one flat colour, or a handful."""
    from PIL import Image, ImageStat

    image = Image.open(io.BytesIO(png)).convert("RGB")
    colours = image.getcolors(maxcolors=1 << 16)
    many = colours is None or len(colours) > 64
    spread = max(ImageStat.Stat(image.convert("L")).stddev) > 20
    return not (many and spread)
