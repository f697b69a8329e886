"""N chassis simulators in one process (for benchmarks/load.py).

    python benchmarks/_simulators.py N

Prints the N pty paths, one per line, then serves until stdin closes.
"""

from __future__ import annotations

import asyncio
import contextlib
import sys

from chassis_sdk.sim import ChassisSimulator


async def main(n: int) -> None:
    async with contextlib.AsyncExitStack() as stack:
        sims = [await stack.enter_async_context(ChassisSimulator()) for _ in range(n)]
        for sim in sims:
            print(sim.port, flush=True)
        loop = asyncio.get_running_loop()
        await loop.run_in_executor(None, sys.stdin.read)


if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1])))
