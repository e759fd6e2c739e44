#!/usr/bin/env python3
"""List every parameter, then change one and read it back (gRPC API)."""

import asyncio

from mavsdk import System


async def run() -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    params = await drone.param.get_all_params()
    for p in params.int_params:
        print(f"{p.name}: {p.value}")
    for p in params.float_params:
        print(f"{p.name}: {p.value:.6g}")
    print(f"-- {len(params.int_params)} int and {len(params.float_params)} float parameters")
    await drone.param.set_param_float("MPC_XY_VEL_MAX", 8.0)
    print(f"-- MPC_XY_VEL_MAX is now {await drone.param.get_param_float('MPC_XY_VEL_MAX'):.1f}")


if __name__ == "__main__":
    asyncio.run(run())
