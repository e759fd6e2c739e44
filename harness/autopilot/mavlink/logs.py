"""The MAVLink log protocol (PX4's ``mavlink_log_handler``): a ground station lists the vehicle's flight logs
and downloads them (MAVSDK ``log_files``, QGroundControl's log download).

- LOG_REQUEST_LIST → one LOG_ENTRY per log in the asked id range (ids from 0; ``num_logs``, ``last_log_num``,
  ``time_utc``, ``size``); with no log, one LOG_ENTRY with ``num_logs`` 0.
- LOG_REQUEST_DATA (id, ofs, count) → LOG_DATA of up to 90 bytes each covering [ofs, ofs + count) clipped to
  the size announced in the entry; at or past the end one LOG_DATA with ``count`` 0.
- LOG_REQUEST_END: accepted (nothing is held open between requests).
- LOG_ERASE: PX4 erases every log; here the only log is the one being written, which is kept.

The logs come from the autopilot's optional ``log_files`` service (``system.log_files.files()``); the size of
each is taken at LOG_REQUEST_LIST (the log keeps growing while it is downloaded, and always ends on a
ULog message boundary at the size announced).
"""

from __future__ import annotations

from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out
from harness.autopilot.services import System

LOG_IDS = frozenset(
    {
        mavlink2.MAVLINK_MSG_ID_LOG_REQUEST_LIST,
        mavlink2.MAVLINK_MSG_ID_LOG_REQUEST_DATA,
        mavlink2.MAVLINK_MSG_ID_LOG_REQUEST_END,
        mavlink2.MAVLINK_MSG_ID_LOG_ERASE,
    }
)
CHUNK = 90
"""LOG_DATA payload bytes."""
MAX_PER_REQUEST = 1024
"""LOG_DATA messages sent for one LOG_REQUEST_DATA at most (MAVSDK asks for 512 at a time)."""


class LogService:
    """Log listing and download for one vehicle. Called from the server thread only."""

    def __init__(self, api: System, mav: mavlink2.MAVLink) -> None:
        self.api = api
        self.mav = mav
        self._entries: list[tuple[Path, int, int]] = []

    def _list(self) -> list[tuple[Path, int, int]]:
        logs = self.api.log_files
        self._entries = logs.files() if logs is not None else []
        return self._entries

    def handle(self, m: MAVLinkMessage, origin: Origin) -> list[Out]:
        mid = m.get_msgId()
        mav = self.mav
        if mid == mavlink2.MAVLINK_MSG_ID_LOG_REQUEST_LIST:
            entries = self._list()
            n = len(entries)
            if n == 0:
                return [Out(mav.log_entry_encode(0, 0, 0, 0, 0), origin)]
            last = min(m.end, n - 1)
            return [
                Out(mav.log_entry_encode(i, n, n - 1, entries[i][2], entries[i][1]), origin)
                for i in range(m.start, last + 1)
            ]
        if mid == mavlink2.MAVLINK_MSG_ID_LOG_REQUEST_DATA:
            return self._data(m.id, m.ofs, m.count, origin)
        return []  # LOG_REQUEST_END, LOG_ERASE

    def _data(self, log_id: int, ofs: int, count: int, origin: Origin) -> list[Out]:
        if not self._entries:
            self._list()
        if not 0 <= log_id < len(self._entries):
            return []
        path, size, _ = self._entries[log_id]
        end = min(size, ofs + min(count, CHUNK * MAX_PER_REQUEST))
        mav = self.mav
        if ofs >= end:
            return [Out(mav.log_data_encode(log_id, ofs, 0, [0] * CHUNK), origin)]
        with path.open("rb") as f:
            f.seek(ofs)
            data = f.read(end - ofs)
        outs = []
        for i in range(0, len(data), CHUNK):
            part = data[i : i + CHUNK]
            outs.append(
                Out(mav.log_data_encode(log_id, ofs + i, len(part), list(part) + [0] * (CHUNK - len(part))), origin)
            )
        return outs
