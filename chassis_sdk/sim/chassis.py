"""The chassis (protocol A) simulator: its firmware model served on a pty or TCP."""

from __future__ import annotations

from ..devices.chassis.firmware import ChassisFirmware, ChassisSpec
from .server import LineFaults, SimulatorServer
from .world import World

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
        spec: Device parameters (versions, geometry, rates, miscalibration, slip).
        world: Walls to run into (`World`), in the frame of the start pose; ``None``:
            open space. ``sim.firmware.true_pose`` is where the robot truly is.
        tcp_port: Serve on ``socket://127.0.0.1:PORT`` instead of a pty (0: any port).
        faults: Line faults to start with (noise, bit flips, lost bytes, late or lost
            replies); ``sim.faults`` can be changed while it runs.

    Raises:
        ValueError: The robot at its start pose touches a wall of ``world``.
    """

    firmware: ChassisFirmware

    def __init__(
        self,
        spec: ChassisSpec | None = None,
        *,
        world: World | None = None,
        tcp_port: int | None = None,
        faults: LineFaults | None = None,
    ) -> None:
        super().__init__(ChassisFirmware(spec, world=world), tcp_port=tcp_port, faults=faults)
