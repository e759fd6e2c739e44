"""A script that leaves a non-daemon thread blocked forever and then raises: the runner must end it."""

import threading

threading.Thread(target=threading.Event().wait, name="stuck-forever").start()
raise RuntimeError("mission failed on purpose")
