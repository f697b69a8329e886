"""The controller board (protocol B) simulator: its firmware model served on a pty or TCP."""

from __future__ import annotations

from ..devices.board.firmware import BoardFirmware, BoardSpec
from .server import LineFaults, SimulatorServer
from .world import World

__all__ = ["BoardSimulator"]


class BoardSimulator(SimulatorServer):
    """The board firmware model served on a pseudo-terminal (default) or TCP.

    Args:
        spec: Rates, dynamics, miscalibration, slip, the robot's footprint.
        world: Walls to run into (`World`), in the frame of the start pose; ``None``:
            open space. ``sim.firmware.true_pose`` is where the robot truly is.
        tcp_port: Serve on ``socket://127.0.0.1:PORT`` instead of a pty (0: any port).
        faults: Line faults to start with (noise, bit flips, lost bytes, late or lost
            replies); ``sim.faults`` can be changed while it runs.

    Raises:
        ValueError: The robot at its start pose touches a wall of ``world``.
    """

    firmware: BoardFirmware

    def __init__(
        self,
        spec: BoardSpec | None = None,
        *,
        world: World | None = None,
        tcp_port: int | None = None,
        faults: LineFaults | None = None,
    ) -> None:
        super().__init__(BoardFirmware(spec, world=world), tcp_port=tcp_port, faults=faults)
