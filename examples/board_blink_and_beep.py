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
            for on in (True, False):
                reported = await board.set_led(on)  # the state the board reports now
                print(f"set_led({on}): the led is {onoff(reported)}")
                await asyncio.sleep(0.2)
        print(f"set_buzzer(True): the buzzer is {onoff(await board.set_buzzer(True))}")
        await asyncio.sleep(0.1)
        print(f"set_buzzer(False): the buzzer is {onoff(await board.set_buzzer(False))}")
        # Requests may overlap: each gets its own request id and its own reply.
        led, buzzer = await asyncio.gather(board.get_led(), board.get_buzzer())
        print(f"now: the led is {onoff(led)}, the buzzer is {onoff(buzzer)}")


def onoff(state: bool) -> str:
    return "on" if state else "off"


if __name__ == "__main__":
    chassis_sdk.run(main(sys.argv[1] if len(sys.argv) > 1 else None), one_line_errors=True)
