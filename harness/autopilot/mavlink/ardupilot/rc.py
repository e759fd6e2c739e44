"""ArduCopter's RC input: SITL's idle radio, RC_CHANNELS_OVERRIDE on top of it, and the sticks it makes.

What the vehicle reads on channel ``n`` (1-based) at sim time ``t``: the override of channel ``n`` while it is
active, else the radio. The radio is ArduPilot SITL's when no transmitter is attached: 1500 us on every channel,
1000 us on the throttle channel (``RCMAP_THROTTLE``). ArduCopter's override rules (``GCS_MAVLINK::
handle_rc_channels_override``, ``RC_Channel::has_override``):

- only from the ground station ``SYSID_MYGCS`` (255 by default, DroneKit's and MAVProxy's system id);
- channels 1-8: ``UINT16_MAX`` leaves the channel as it is, 0 releases it to the radio; channels 9-18: 0 and
  ``UINT16_MAX`` both leave it;
- an override lasts ``RC_OVERRIDE_TIME`` seconds (3) after the message that set it; 0 disables overrides, a
  negative value keeps them without a time-out.

The sticks, as ArduCopter reads its channels (``RCMAP_ROLL/PITCH/THROTTLE/YAW``; ``RCn_MIN/TRIM/MAX``,
``RCn_DZ`` dead zones, ``RCn_REVERSED``; pitch stick back = high PWM; in the altitude-holding modes
``THR_DZ`` around mid throttle), become the core's MANUAL_CONTROL axes (``harness.autopilot.manual``).
"""

from __future__ import annotations

from harness.autopilot.params import Params

CHANNELS = 18
"""RC_CHANNELS carries 18 channels; SITL's radio reports 16."""
RADIO_CHANNELS = 16
UINT16_MAX = 0xFFFF


def _stick(pwm: float, lo: float, trim: float, hi: float, dz: float) -> float:
    """-1..1 around the trim with a dead zone (ArduPilot's ``pwm_to_angle_dz_trim``)."""
    if pwm > trim + dz and hi > trim + dz:
        return min((pwm - trim - dz) / (hi - trim - dz), 1.0)
    if pwm < trim - dz and trim - dz > lo:
        return max((pwm - trim + dz) / (trim - dz - lo), -1.0)
    return 0.0


class RcInput:
    """The RC channels of one ArduCopter vehicle (server thread; times are the vehicle's sim time)."""

    def __init__(self, params: Params) -> None:
        self.params = params
        self._value = [0] * CHANNELS
        self._at_ns = [0] * CHANNELS
        self.received = False
        """An override was ever accepted (the sticks then drive the stick modes)."""

    def reset(self) -> None:
        """A reboot: every override gone."""
        self._value = [0] * CHANNELS
        self._at_ns = [0] * CHANNELS
        self.received = False

    # ------------------------------------------------------------------ input
    def override(self, sysid: int, values: list[int], t_ns: int) -> bool:
        """One RC_CHANNELS_OVERRIDE (``values``: chan1_raw ... chan18_raw); False when ArduCopter ignores it."""
        if sysid != int(self.params["SYSID_MYGCS"]) or self.params["RC_OVERRIDE_TIME"] == 0:
            return False
        for i, v in enumerate(values[:CHANNELS]):
            if v == UINT16_MAX or (i >= 8 and v == 0):
                continue
            self._value[i] = v
            self._at_ns[i] = t_ns
        self.received = True
        return True

    def active(self, ch: int, t_ns: int) -> bool:
        """Whether the override of channel ``ch`` (0-based) is in force at ``t_ns``."""
        if self._value[ch] == 0:
            return False
        timeout = self.params["RC_OVERRIDE_TIME"]
        if timeout == 0:
            return False
        return timeout < 0 or t_ns - self._at_ns[ch] < timeout * 1e9

    def any_active(self, t_ns: int) -> bool:
        return any(self.active(ch, t_ns) for ch in range(CHANNELS))

    # ------------------------------------------------------------------ output
    def pwm(self, ch: int, t_ns: int) -> int:
        """What channel ``ch`` (0-based) reads: the override, else SITL's radio (0 beyond its 16 channels)."""
        if self.active(ch, t_ns):
            return self._value[ch]
        if ch >= RADIO_CHANNELS:
            return 0
        return 1000 if ch + 1 == int(self.params["RCMAP_THROTTLE"]) else 1500

    def channels(self, t_ns: int) -> list[int]:
        return [self.pwm(ch, t_ns) for ch in range(CHANNELS)]

    def _axis(self, mapped: str, t_ns: int) -> float:
        n = int(self.params[mapped])
        if not 1 <= n <= CHANNELS:
            return 0.0
        p = self.params
        lo, trim, hi = (p[f"RC{n}_{k}"] if n <= 16 else d for k, d in (("MIN", 1100), ("TRIM", 1500), ("MAX", 1900)))
        dz = p[f"RC{n}_DZ"] if n <= 16 else 0.0
        v = _stick(self.pwm(n - 1, t_ns), lo, trim, hi, dz)
        return -v if n <= 16 and int(p[f"RC{n}_REVERSED"]) else v

    def throttle(self, t_ns: int, alt_hold: bool) -> float:
        """0..1; in the modes that hold altitude, mid stick within ``THR_DZ`` reads exactly 0.5."""
        n = int(self.params["RCMAP_THROTTLE"])
        if not 1 <= n <= 16:
            return 0.0
        p = self.params
        lo, hi = p[f"RC{n}_MIN"], p[f"RC{n}_MAX"]
        pwm = float(self.pwm(n - 1, t_ns))
        if hi <= lo:
            return 0.0
        if int(p[f"RC{n}_REVERSED"]):
            pwm = lo + hi - pwm
        if not alt_hold:
            return min(max((pwm - lo) / (hi - lo), 0.0), 1.0)
        mid, dz = (lo + hi) / 2.0, p["THR_DZ"]
        return 0.5 + 0.5 * _stick(pwm, lo, mid, hi, dz)

    def sticks(self, t_ns: int, alt_hold: bool) -> tuple[int, int, int, int]:
        """The core's MANUAL_CONTROL axes: x forward, y right, r clockwise (-1000..1000), z throttle (0..1000)."""
        roll = self._axis("RCMAP_ROLL", t_ns)
        pitch = self._axis("RCMAP_PITCH", t_ns)
        yaw = self._axis("RCMAP_YAW", t_ns)
        thr = self.throttle(t_ns, alt_hold)
        return (round(-pitch * 1000), round(roll * 1000), round(thr * 1000), round(yaw * 1000))
