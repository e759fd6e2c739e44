"""Each vehicle broadcasts its index and send time 10 times, once per sim second, and records what it hears."""

import json
import time

from harness.net import radio

me = radio.vehicle()
heard = []
for i in range(10):
    radio.broadcast(json.dumps({"from": me, "i": i, "sent_s": time.monotonic()}).encode())
    end = time.monotonic() + 1.0
    while (left := end - time.monotonic()) > 0:
        msg = radio.receive(timeout=left)
        if msg is not None:
            heard.append(
                {"src": msg.src, "at_s": msg.received_at_s, "now_s": time.monotonic(), **json.loads(msg.payload)}
            )
print(json.dumps(heard))
