"""Simulators: the devices' sans-IO firmware models, served on a pty or TCP.

They are the embedded default that the examples, the CLI demo and the tests run
against when no hardware is attached::

    from chassis_sdk import Chassis
    from chassis_sdk.sim import ChassisSimulator

    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await robot.set_velocity(0.3, 0.0)

``sim.port`` is the pty's path (``/dev/pts/N``) or, with ``tcp_port=``, a
``socket://127.0.0.1:PORT`` URL. ``sim.firmware`` is the model, for device faults
(bumper, driver faults, e-stop, ``reset``) and the truth (``sim.firmware.true_pose``);
``sim.command("bumper front")`` injects a fault by its command line; ``sim.faults``
(`LineFaults`) damages the line; ``sim.unplug()`` / ``await sim.replug()`` pull and
restore the cable. ``ChassisSimulator(world=World.arena(4, 3))`` puts the robot in a
room with walls to run into.

* `.server`: `SimulatorServer`, which serves any firmware model, and the
  line faults;
* `.chassis`, `.board`: the two built-in devices' simulators;
* `.world`: `World`, the walls;
* `.control`: the runtime commands (``apply(firmware, line, now)``);
* `simulator`: the simulator of any registered device, by name.

Each firmware model lives with its device (``chassis_sdk.devices.NAME.firmware``).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from ..core.pack import PackSpec
from ..devices import profile
from ..devices.board.firmware import BoardFirmware, BoardSpec
from ..devices.chassis.firmware import ChassisFirmware, ChassisSpec
from .board import BoardSimulator
from .chassis import ChassisSimulator
from .server import FaultCounts, LineFaults, SimulatorServer
from .world import Wall, World

__all__ = [
    "BoardFirmware",
    "BoardSimulator",
    "BoardSpec",
    "ChassisFirmware",
    "ChassisSimulator",
    "ChassisSpec",
    "FaultCounts",
    "LineFaults",
    "PackSpec",
    "SimulatorServer",
    "Wall",
    "World",
    "simulator",
]


def simulator(
    device: str,
    *,
    tcp_port: int | None = None,
    faults: LineFaults | None = None,
    world: World | None = None,
) -> SimulatorServer:
    """A simulator of the registered device called ``device`` (its firmware model,
    fresh, on a pty or on ``127.0.0.1:tcp_port``), not yet started.

    Args:
        device: The registered device's name.
        tcp_port: Serve on TCP instead of a pty (0: any free port).
        faults: Line faults to start with.
        world: Walls to run into; only for a model with a ``world`` (the chassis and
            the board have one).

    Raises:
        ValueError: No such device; a world for a model without one; the robot at its
            start pose touches a wall of ``world``.
    """
    firmware = profile(device).firmware()
    if world is not None:
        if not isinstance(firmware, _Inhabited):
            raise ValueError(f"the {device} simulator has no world (the chassis and board do)")
        firmware.world = world
    return SimulatorServer(firmware, tcp_port=tcp_port, faults=faults)


@runtime_checkable
class _Inhabited(Protocol):
    """A firmware model that can be put in a world."""

    world: World | None
