"""Simulators: the devices' sans-IO firmware models, served on a pty or TCP.

They are the embedded default that the examples, the CLI demo and the tests run
against when no hardware is attached::

    from chassis_sdk import Chassis
    from chassis_sdk.sim import ChassisSimulator

    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await robot.set_velocity(0.3, 0.0)

``sim.port`` is the pty's path (``/dev/pts/N``) or, with ``tcp_port=``, a
``socket://127.0.0.1:PORT`` URL. ``sim.firmware`` is the model, for device faults
(bumper, driver faults, e-stop, ``reset``); ``sim.faults`` (`LineFaults`) damages
the line; ``sim.unplug()`` / ``await sim.replug()`` pull and restore the cable.

* `.server`: `SimulatorServer`, which serves any firmware model, and the
  line faults;
* `.chassis`, `.board`: the two built-in devices' simulators;
* `simulator`: the simulator of any registered device, by name.

Each firmware model lives with its device (``chassis_sdk.devices.NAME.firmware``).
"""

from __future__ import annotations

from ..core.pack import PackSpec
from ..devices import profile
from ..devices.board.firmware import BoardFirmware, BoardSpec
from ..devices.chassis.firmware import ChassisFirmware, ChassisSpec
from .board import BoardSimulator
from .chassis import ChassisSimulator
from .server import FaultCounts, LineFaults, SimulatorServer

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
    "simulator",
]


def simulator(
    device: str, *, tcp_port: int | None = None, faults: LineFaults | None = None
) -> SimulatorServer:
    """A simulator of the registered device called ``device`` (its firmware model,
    fresh, on a pty or on ``127.0.0.1:tcp_port``), not yet started.

    Raises:
        ValueError: No such device.
    """
    return SimulatorServer(profile(device).firmware(), tcp_port=tcp_port, faults=faults)
