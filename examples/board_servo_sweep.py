"""Sweep servo 1 from 0 to 90 degrees and back, printing the board's log lines.

python examples/board_servo_sweep.py [PORT]
"""

from __future__ import annotations

import asyncio
import contextlib
import sys

import chassis_sdk
from chassis_sdk import Board
from chassis_sdk.sim import BoardSimulator


async def print_logs(board: Board) -> None:
    async for line in board.logs():
        print("board:", line)


async def main(port: str | None) -> None:
    async with contextlib.AsyncExitStack() as stack:
        if port is None:
            port = (await stack.enter_async_context(BoardSimulator())).port
        board = await stack.enter_async_context(Board(port))
        await board.verify()  # the device on the port is a board
        async with asyncio.TaskGroup() as tg:
            logger = tg.create_task(print_logs(board))
            for angle in [*range(0, 91, 15), *range(75, -1, -15)]:
                await board.set_servo(1, angle)
                await asyncio.sleep(0.05)
            await asyncio.sleep(0.1)  # let the last log lines arrive
            logger.cancel()


if __name__ == "__main__":
    chassis_sdk.run(main(sys.argv[1] if len(sys.argv) > 1 else None), one_line_errors=True)
