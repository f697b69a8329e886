"""Make docs/img/web.png: the dashboard of a simulated chassis after a short drive, in
headless Chromium (Debian's, through Playwright). Run from the repository's root:
``python tools/web_screenshot.py [OUT.png]``."""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

from playwright.async_api import expect

from chassis_sdk import Chassis, MotionLimits
from chassis_sdk.integrations.web import WebDashboard
from chassis_sdk.sim import ChassisSimulator

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from tests.support.browser import chromium, is_blank

#: The keys held, and for how long (s): a path with a turn in it.
DRIVE = [("KeyW", 1.5), ("KeyA", 1.2), ("KeyW", 1.2), ("KeyD", 0.6), ("KeyW", 0.8)]


async def main(out: Path) -> None:
    limits = MotionLimits(max_linear=0.5, max_angular=1.0)
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port, limits=limits) as robot,
        WebDashboard(robot, port=0) as web,
        chromium() as browser,
    ):
        page = await browser.new_page(viewport={"width": 1280, "height": 900})
        await page.goto(web.url)
        await expect(page.locator("#link")).to_have_text("link connected")
        for key, seconds in DRIVE:
            await page.keyboard.down(key)
            await asyncio.sleep(seconds)
            await page.keyboard.up(key)
        await page.keyboard.down("KeyW")  # caught while moving
        await asyncio.sleep(0.7)
        png = await page.screenshot(full_page=True)
        await page.keyboard.up("KeyW")
    assert not is_blank(png), "the screenshot is blank"
    await asyncio.to_thread(out.write_bytes, png)
    print(f"wrote {out} ({len(png):,} bytes)")


if __name__ == "__main__":
    asyncio.run(main(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/img/web.png")))
