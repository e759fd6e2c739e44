"""A child for tests/run/test_forkserver.py, run as ``python -m tests.run.forked_child CODE [SLEEP_S]``: it
prints what it was started with (argv, two environment variables, its process group, cwd) and exits with CODE."""

from __future__ import annotations

import json
import os
import sys
import time

if __name__ == "__main__":
    print(
        json.dumps(
            {
                "argv": sys.argv[1:],
                "env": os.environ.get("FORKED_TEST"),
                "extra": os.environ.get("EXTRA"),
                "pgid": os.getpgid(0),
                "pid": os.getpid(),
                "cwd": os.getcwd(),
                "main": __name__,
                "wave": "wave" in sys.modules,  # preloaded by the fork server (test_forkserver), not imported here
            }
        )
    )
    print("to stderr", file=sys.stderr)
    sys.stdout.flush()
    if len(sys.argv) > 2:
        time.sleep(float(sys.argv[2]))
    raise SystemExit(int(sys.argv[1]))
