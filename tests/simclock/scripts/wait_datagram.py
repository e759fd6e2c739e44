"""Wait, with no timeout, for one UDP datagram on the port named in argv[1]; print it and the sim time."""

import asyncio
import json
import socket
import sys
import time


async def main() -> None:
    loop = asyncio.get_running_loop()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", int(sys.argv[1])))
    sock.setblocking(False)
    data = await loop.sock_recv(sock, 100)
    print(json.dumps({"payload": data.decode(), "at_s": time.monotonic()}))


asyncio.run(main())
