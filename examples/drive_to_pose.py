"""Drive to poses using odometry: a 1 m square, closed on the odometry itself.

    python examples/drive_to_pose.py [PORT]

`drive_to(robot, x, y)` turns towards the point, then drives to it, steering on the way
and slowing down as it arrives, with the pose from `robot.odometry()` as feedback and
`set_velocity()` called on every new pose (50 Hz). Against the built-in simulator the
example also prints the simulator's true pose, so you can see how far odometry drifts.
"""

from __future__ import annotations

import contextlib
import math
import sys

import chassis_sdk
from chassis_sdk import Chassis, Odometry
from chassis_sdk.core.odometry import wrap_angle
from chassis_sdk.sim import ChassisSimulator

SPEED = 0.8  # m/s, cruising
TURN_RATE = 2.0  # rad/s, largest
ACCEL = 1.2  # m/s², planned braking (the chassis can do 1.5)
ANGULAR_ACCEL = 3.0  # rad/s², planned braking in turns


def _clamp(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


async def turn_to(robot: Chassis, heading: float, *, tolerance: float = math.radians(1)) -> None:
    """Turn in place until the odometry heading is within `tolerance` of `heading`."""
    async with robot.odometry() as poses:
        async for pose in poses:
            error = wrap_angle(heading - pose.heading)
            if abs(error) < tolerance:
                break
            # Brake in time: the rate whose stopping angle is the error left.
            rate = min(TURN_RATE, math.sqrt(2 * ANGULAR_ACCEL * abs(error)))
            await robot.set_velocity(0.0, math.copysign(max(rate, 0.1), error))
    await settle(robot)


async def drive_to(robot: Chassis, x: float, y: float, *, tolerance: float = 0.01) -> Odometry:
    """Turn towards (x, y), drive there, stop; return the pose reached."""
    start = robot.latest_odometry
    if start is not None:
        await turn_to(robot, math.atan2(y - start.y, x - start.x))
    async with robot.odometry() as poses:
        async for pose in poses:
            distance = pose.distance_to(x, y)
            bearing_error = wrap_angle(math.atan2(y - pose.y, x - pose.x) - pose.heading)
            if distance < tolerance or abs(bearing_error) > math.pi / 2:
                break  # there, or just past it
            speed = min(SPEED, math.sqrt(2 * ACCEL * distance), max(0.05, 2 * distance))
            await robot.set_velocity(speed, _clamp(3.0 * bearing_error, TURN_RATE))
    return await settle(robot)


async def settle(robot: Chassis) -> Odometry:
    """Stop, and wait until the chassis reports standing still."""
    await robot.stop()
    async with robot.odometry() as poses:
        async for pose in poses:
            if abs(pose.linear) < 1e-3 and abs(pose.angular) < 1e-3:
                return pose
    raise RuntimeError("odometry ended")


async def square(robot: Chassis, side: float = 1.0) -> Odometry:
    """Drive a square counter-clockwise back to the start and face the start heading."""
    await anext(robot.odometry())  # the first pose, so turning starts from a known heading
    robot.reset_odometry()
    for corner, (x, y) in enumerate([(side, 0.0), (side, side), (0.0, side), (0.0, 0.0)], 1):
        print(f"corner {corner}/4: driving to ({x:.1f}, {y:.1f}) m ...", flush=True)
        pose = await drive_to(robot, x, y)
        print(f"corner {corner}/4: reached ({pose.x:+.3f}, {pose.y:+.3f}) m", flush=True)
    print("turning back to the start heading ...", flush=True)
    await turn_to(robot, 0.0)
    return await settle(robot)


async def main(port: str | None) -> None:
    async with contextlib.AsyncExitStack() as stack:
        sim = None
        if port is None:
            sim = await stack.enter_async_context(ChassisSimulator())
            port = sim.port
        robot = await stack.enter_async_context(Chassis(port))
        await robot.verify()  # the device on the port is a chassis
        end = await square(robot)
        print(f"odometry at the end: x={end.x:+.3f} m  y={end.y:+.3f} m  "
              f"heading={math.degrees(end.heading):+.1f} deg")  # fmt: skip
        if sim is not None:
            x, y, h = sim.firmware.pose
            print(f"simulator's truth:   x={x:+.3f} m  y={y:+.3f} m  "
                  f"heading={math.degrees(wrap_angle(h)):+.1f} deg")  # fmt: skip
            print(f"odometry error: {math.hypot(end.x - x, end.y - y) * 100:.1f} cm")


if __name__ == "__main__":
    chassis_sdk.run(main(sys.argv[1] if len(sys.argv) > 1 else None), one_line_errors=True)
