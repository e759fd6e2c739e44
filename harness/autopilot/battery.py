"""Battery model: charge drawn by the motors' electrical power, open-circuit voltage curve, voltage sag.

Motor electrical power is ``SIM_MOT_POWER · u³`` for a normalised command ``u`` (thrust grows with u²,
induced power with thrust^1.5), plus a small avionics load: about 180 W at the FDM's hover command 0.72. ``SIM_BAT_DRAIN`` multiplies the drain so
tests can reach the low-battery thresholds in seconds.
"""

from __future__ import annotations

from harness.autopilot.api import BatteryState
from harness.autopilot.params import Params

AVIONICS_W = 5.0


class Battery:
    def __init__(self, params: Params) -> None:
        self.params = params
        self.consumed_mah = 0.0
        self.current_a = 0.0
        self.voltage_v = params["BAT_N_CELLS"] * params["BAT_V_CHARGED"]

    @property
    def remaining(self) -> float:
        cap = self.params["BAT_CAPACITY"]
        return max(0.0, 1.0 - self.consumed_mah / cap) if cap > 0 else 1.0

    def open_circuit_v(self) -> float:
        p = self.params
        soc = self.remaining
        # a mild knee: flat in the middle, steeper near empty
        shape = soc**0.7 if soc > 0 else 0.0
        return p["BAT_N_CELLS"] * (p["BAT_V_EMPTY"] + (p["BAT_V_CHARGED"] - p["BAT_V_EMPTY"]) * shape)

    def update(self, motors: tuple[float, ...], armed: bool, dt: float) -> None:
        p = self.params
        pm = p["SIM_MOT_POWER"]
        power = AVIONICS_W + (sum(pm * u * u * u for u in motors) if armed else 0.0)
        v_oc = self.open_circuit_v()
        r = p["BAT_R_INTERNAL"]
        # P = V I with V = Voc - R I  ->  R I^2 - Voc I + P = 0
        disc = v_oc * v_oc - 4.0 * r * power
        i = (v_oc - disc**0.5) / (2.0 * r) if r > 0 and disc > 0 else power / max(v_oc, 1e-3)
        self.current_a = i
        self.voltage_v = v_oc - r * i
        self.consumed_mah += i * dt / 3.6 * p["SIM_BAT_DRAIN"]

    def state(self) -> BatteryState:
        return BatteryState(
            voltage_v=self.voltage_v,
            current_a=self.current_a,
            remaining=self.remaining,
            consumed_mah=self.consumed_mah,
            cells=int(self.params["BAT_N_CELLS"]),
        )
