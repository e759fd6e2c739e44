#!/usr/bin/env python3
"""Gimbal (as MAVSDK's gimbal example): find the gimbal, take control, point it forward, down, up at a rate,
right, at a region of interest, and release it, printing its attitude as it moves (gRPC API).

MAVSDK's own example waits for gimbal_list() with wait_for(..., 10 s) around a stream that never ends, so it
always times out and then iterates over None; this one stops at the first list that has a gimbal."""

import asyncio

from mavsdk import System
from mavsdk.gimbal import ControlMode, GimbalMode, SendMode


async def first_gimbal(drone: System):
    async for gimbal_list in drone.gimbal.gimbal_list():
        for gimbal in gimbal_list.gimbals:
            print(
                f"Found gimbal: id={gimbal.gimbal_id}, model={gimbal.model_name}, "
                f"vendor={gimbal.vendor_name}, device id={gimbal.gimbal_device_id}"
            )
            return gimbal


async def print_attitude(drone: System, gimbal_id: int) -> None:
    while True:
        attitude = await drone.gimbal.get_attitude(gimbal_id)
        e = attitude.euler_angle_forward
        print(f"Gimbal {gimbal_id} pitch: {e.pitch_deg:.1f}, yaw: {e.yaw_deg:.1f}")
        await asyncio.sleep(0.5)


async def run() -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    gimbal = await asyncio.wait_for(first_gimbal(drone), timeout=10)
    gid = gimbal.gimbal_id
    printer = asyncio.create_task(print_attitude(drone, gid))
    print("-- Taking control")
    await drone.gimbal.take_control(gid, ControlMode.PRIMARY)
    async for status in drone.gimbal.control_status():
        print(f"-- Control: {status.control_mode}")
        break
    for label, pitch, yaw in (("forward", 0, 0), ("down", -90, 0), ("forward", 0, 0)):
        print(f"-- Look {label}")
        await drone.gimbal.set_angles(gid, 0, pitch, yaw, GimbalMode.YAW_FOLLOW, SendMode.ONCE)
        await asyncio.sleep(3)
    print("-- Slowly look up at 5 deg/s")
    await drone.gimbal.set_angular_rates(gid, 0, 5, 0, GimbalMode.YAW_FOLLOW, SendMode.STREAM)
    await asyncio.sleep(4)
    print("-- Look right")
    await drone.gimbal.set_angles(gid, 0, 0, 90, GimbalMode.YAW_FOLLOW, SendMode.ONCE)
    await asyncio.sleep(3)
    print("-- Look at a point 50 m north, on the ground")
    async for home in drone.telemetry.home():
        break
    await drone.gimbal.set_roi_location(
        gid, home.latitude_deg + 50 / 111_320, home.longitude_deg, home.absolute_altitude_m
    )
    await asyncio.sleep(3)
    print("-- Release control")
    await drone.gimbal.release_control(gid)
    printer.cancel()


if __name__ == "__main__":
    asyncio.run(run())
