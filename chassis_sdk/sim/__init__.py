"""Simulators: sans-IO firmware models of both devices, served on a pty or TCP.

They are the embedded default that the examples, the CLI demo and the tests run
against when no hardware is attached::

    from chassis_sdk import Chassis
    from chassis_sdk.sim import ChassisSimulator

    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await robot.set_velocity(0.3, 0.0)

``sim.port`` is the pty's path (``/dev/pts/N``) or, with ``tcp_port=``, a
``socket://127.0.0.1:PORT`` URL. ``sim.firmware`` is the model, for device faults
(bumper, driver faults, e-stop, ``reset``); ``sim.faults`` (:class:`LineFaults`) damages
the line; ``sim.unplug()`` / ``await sim.replug()`` pull and restore the cable.

The server lives in :mod:`chassis_sdk.core.simulator`, each firmware model with its
device (:mod:`chassis_sdk.devices`); every device's simulator is
``chassis_sdk.devices.profile(name).simulator``.
"""

from ..core.simulator import FaultCounts, LineFaults, SimulatorServer
from ..devices.board.firmware import BoardFirmware, BoardSimulator, BoardSpec
from ..devices.chassis.firmware import ChassisFirmware, ChassisSimulator, ChassisSpec

__all__ = [
    "BoardFirmware",
    "BoardSimulator",
    "BoardSpec",
    "ChassisFirmware",
    "ChassisSimulator",
    "ChassisSpec",
    "FaultCounts",
    "LineFaults",
    "SimulatorServer",
]
