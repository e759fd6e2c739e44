"""Real I/O under the patched loop: UDP echo over loopback, then a wait_for that times out."""

import asyncio
import json
import time


class Echo(asyncio.DatagramProtocol):
    def connection_made(self, transport):
        self.transport = transport

    def datagram_received(self, data, addr):
        self.transport.sendto(data, addr)


class Client(asyncio.DatagramProtocol):
    def __init__(self):
        self.replies = asyncio.Queue()

    def datagram_received(self, data, addr):
        self.replies.put_nowait(data)


async def main() -> None:
    loop = asyncio.get_running_loop()
    server, _ = await loop.create_datagram_endpoint(Echo, local_addr=("127.0.0.1", 0))
    port = server.get_extra_info("sockname")[1]
    transport, client = await loop.create_datagram_endpoint(Client, remote_addr=("127.0.0.1", port))
    got = []
    for i in range(20):
        transport.sendto(f"ping {i}".encode())
        got.append((await asyncio.wait_for(client.replies.get(), timeout=3)).decode())
    server.close()  # nobody answers any more
    t0 = time.monotonic()
    transport.sendto(b"lost")
    try:
        await asyncio.wait_for(client.replies.get(), timeout=3)
        timed_out = False
    except TimeoutError:
        timed_out = True
    print(json.dumps({"replies": got, "timed_out": timed_out, "waited": time.monotonic() - t0}))


asyncio.run(main())
