"""Data-link loss (PX4 ``NAV_DLL_ACT``): when every ground station has been silent for ``COM_DL_LOSS_T``
seconds of wall time (10 s when the parameter does not exist) while the vehicle flies, act once.

Only heartbeats of ground stations (MAV_TYPE_GCS, what MAVSDK and QGC send) count as the link, and only
after one was heard: a vehicle nobody ever connected to has not lost anything. Actions: 0 disabled,
1 hold, 2 return, 3 land (PX4's 5 terminate and 6 lockdown are not offered and behave as 3 land).
"""

from __future__ import annotations

from dataclasses import dataclass

from harness.autopilot.api import CommandResult, VehicleState
from harness.autopilot.services import System

DEFAULT_LOSS_S = 10.0


@dataclass(slots=True)
class DataLinkMonitor:
    api: System
    last_gcs_ns: int | None = None
    triggered: bool = False

    def heard_gcs(self, now_ns: int) -> None:
        self.last_gcs_ns = now_ns
        self.triggered = False

    def _param(self, name: str, default: float) -> float:
        try:
            return float(self.api.params.get(name))
        except KeyError:
            return default

    def check(self, state: VehicleState, now_ns: int) -> str:
        """'' normally; the STATUSTEXT to send when the loss action was just taken."""
        if self.last_gcs_ns is None or self.triggered or not (state.armed and state.in_air):
            return ""
        action = int(self._param("NAV_DLL_ACT", 0))
        if action <= 0:
            return ""
        loss_s = self._param("COM_DL_LOSS_T", DEFAULT_LOSS_S)
        silent_s = (now_ns - self.last_gcs_ns) / 1e9
        if silent_s <= loss_s:
            return ""
        self.triggered = True
        result: CommandResult
        if action == 1:
            result, what = self.api.action.hold(), "holding"
        elif action == 2:
            result, what = self.api.action.return_to_launch(), "returning"
        else:
            result, what = self.api.action.land(), "landing"
        if not result.ok:
            return f"Data link lost for {silent_s:.0f} s: {what} refused ({result.reason})"
        return f"Data link lost for {silent_s:.0f} s: {what}"
