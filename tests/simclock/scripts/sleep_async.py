"""An asyncio script: await asyncio.sleep(5) must take 5 s of sim time."""

import asyncio
import json
import time


async def main() -> None:
    loop = asyncio.get_running_loop()
    t0, l0 = time.time(), loop.time()
    await asyncio.sleep(5)
    print(json.dumps({"time": time.time() - t0, "loop": loop.time() - l0}))


asyncio.run(main())
