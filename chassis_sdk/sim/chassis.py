"""The chassis (protocol A) simulator: its firmware model served on a pty or TCP."""

from __future__ import annotations

from ..devices.chassis.firmware import ChassisFirmware, ChassisSpec
from .server import LineFaults, SimulatorServer

__all__ = ["ChassisSimulator"]


class ChassisSimulator(SimulatorServer):
    """The chassis firmware model served on a pseudo-terminal (default) or TCP.

    Example:
        ```python
        async def main() -> None:
            async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
                print(await robot.get_firmware_version())
        ```

    Args:
        spec: Device parameters (versions, geometry, rates).
        tcp_port: Serve on ``socket://127.0.0.1:PORT`` instead of a pty (0: any port).
        faults: Line faults to start with (noise, bit flips, lost bytes, late or lost
            replies); ``sim.faults`` can be changed while it runs.
    """

    firmware: ChassisFirmware

    def __init__(
        self,
        spec: ChassisSpec | None = None,
        *,
        tcp_port: int | None = None,
        faults: LineFaults | None = None,
    ) -> None:
        super().__init__(ChassisFirmware(spec), tcp_port=tcp_port, faults=faults)
