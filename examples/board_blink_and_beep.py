"""Blink the LED and beep the buzzer; each call returns the state the board reports.

python examples/board_blink_and_beep.py [PORT]
"""

from __future__ import annotations

import asyncio
import contextlib
import sys

import chassis_sdk
from chassis_sdk import Board
from chassis_sdk.sim import BoardSimulator


async def main(port: str | None) -> None:
    async with contextlib.AsyncExitStack() as stack:
        if port is None:
            port = (await stack.enter_async_context(BoardSimulator())).port
        board = await stack.enter_async_context(Board(port))
        await board.verify()  # the device on the port is a board
        for _ in range(3):
            print("led on:", await board.set_led(True))
            await asyncio.sleep(0.2)
            print("led off:", not await board.set_led(False))
            await asyncio.sleep(0.2)
        print("beep:", await board.set_buzzer(True))
        await asyncio.sleep(0.1)
        await board.set_buzzer(False)
        # Requests may overlap: each gets its own request id and its own reply.
        led, buzzer = await asyncio.gather(board.get_led(), board.get_buzzer())
        print(f"now: led={led} buzzer={buzzer}")


if __name__ == "__main__":
    chassis_sdk.run(main(sys.argv[1] if len(sys.argv) > 1 else None), one_line_errors=True)
