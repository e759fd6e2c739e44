#!/usr/bin/env python3
"""Sensor calibration (as MAVSDK's calibration example): gyro, accelerometer, magnetometer and level horizon in
turn, printing each progress update and instruction the vehicle reports (gRPC API)."""

import asyncio

from mavsdk import System


async def calibrate(name: str, updates) -> None:
    print(f"-- Starting {name} calibration")
    steps = 0
    async for progress in updates:
        steps += 1
        if progress.has_status_text:
            print(f"   {name}: {progress.status_text}")
        elif progress.has_progress:
            print(f"   {name}: {round(progress.progress * 100)} %")
    print(f"-- {name} calibration finished after {steps} updates")


async def run() -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            print("-- Connected to drone!")
            break
    cal = drone.calibration
    await calibrate("gyroscope", cal.calibrate_gyro())
    await calibrate("accelerometer", cal.calibrate_accelerometer())
    await calibrate("magnetometer", cal.calibrate_magnetometer())
    await calibrate("level horizon", cal.calibrate_level_horizon())
    gyro_id = await drone.param.get_param_int("CAL_GYRO0_ID")
    roll = await drone.param.get_param_float("SENS_BOARD_X_OFF")
    print(f"-- CAL_GYRO0_ID {gyro_id}, SENS_BOARD_X_OFF {roll:.3f} deg")


if __name__ == "__main__":
    asyncio.run(run())
