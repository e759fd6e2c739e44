#!/usr/bin/env python3
"""The MAVLink shell (as MAVSDK's shell example, with the commands given here instead of typed): each command
goes to the vehicle's nsh and its answer is printed (gRPC API; mavsdk-grpc 4 asks for the device in send()).
Commands: the arguments, or a default set."""

import asyncio
import sys

from mavsdk import System
from mavsdk.shell import Device

COMMANDS = ["ver all", "param show MIS_TAKEOFF_ALT", "param set MIS_TAKEOFF_ALT 4", "listener vehicle_status"]


async def run() -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            print("-- Connected to drone!")
            break
    received: asyncio.Queue[str] = asyncio.Queue()

    async def observe() -> None:
        async for output in drone.shell.receive():
            await received.put(output.data)

    observer = asyncio.create_task(observe())
    await asyncio.sleep(0.5)  # the receive stream is subscribed before the first command
    for command in sys.argv[1:] or COMMANDS:
        await drone.shell.send(command, Device.SHELL)
        answer = ""
        while not answer.endswith("nsh> "):  # the prompt ends every answer
            answer += await asyncio.wait_for(received.get(), timeout=5)
        print(answer, end="", flush=True)
    print()
    observer.cancel()


if __name__ == "__main__":
    asyncio.run(run())
