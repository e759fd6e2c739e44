"""Swarm code that knows nothing of the harness: plain UDP broadcast on port 5005, a 1 s receive timeout."""

import json
import os
import socket
import time

me = int(os.environ.get("HARNESS_VEHICLE", "0"))
sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
sock.bind(("0.0.0.0", 5005 + 0))
sock.settimeout(1.0)
heard = []
timeouts = 0
for i in range(5):
    sock.sendto(json.dumps({"from": me, "i": i}).encode(), ("10.42.0.255", 5005))
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        try:
            data, addr = sock.recvfrom(1500)
        except TimeoutError:
            timeouts += 1
            break
        heard.append({"addr": addr[0], **json.loads(data)})
if me == 0:  # a unicast reply path: ask vehicle 1 directly
    sock.sendto(b"direct", ("10.42.0.2", 5005))
print(json.dumps({"heard": heard, "timeouts": timeouts}))
