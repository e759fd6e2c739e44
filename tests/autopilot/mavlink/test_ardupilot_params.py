"""ArduCopter's parameter table: the generated data, the firmware-neutral loader, ArduCopter's PARAM_SET rules
for the parameters that are stored (accepted, not flown), and the per-vehicle saving of a personality's table."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from harness.autopilot.firmware import Firmware
from harness.autopilot.mavlink.ardupilot.params import CopterParams, copter_table, stored_value
from harness.autopilot.mavlink.param_store import persist_params, store_path
from harness.autopilot.mavlink.personality import core_param_defaults
from harness.autopilot.param_table import load_param_table
from harness.autopilot.params import Params, ParamType
from harness.core.errors import ScenarioError


def _copter() -> tuple[Params, CopterParams]:
    core = Params(overrides=core_param_defaults(Firmware.ARDUPILOT))
    return core, CopterParams(core, 1)


def test_the_table_is_arducopter_4_2_with_more_than_a_thousand_parameters() -> None:
    t = copter_table()
    assert len(t) > 1000 and "ArduCopter 4.2" in t.source and "qgroundcontrol" in t.source
    names = [d.name for d in t.defs]
    assert len(set(names)) == len(names)
    assert not any(n.startswith("H_") for n in names)  # helicopter groups: a quad X has none
    assert t.ranges["WPNAV_SPEED"] == (20.0, 2000.0) and t.ranges["RC_OVERRIDE_TIME"] == (0.0, 120.0)
    assert "FORMAT_VERSION" in t.read_only
    d = {x.name: x for x in t.defs}
    assert d["RC3_MIN"].default == 1100 and d["RC3_TRIM"].default == 1500 and d["RCMAP_THROTTLE"].default == 3
    assert d["FS_THR_ENABLE"].type == ParamType.INT32 and d["WPNAV_SPEED"].type == ParamType.FLOAT
    assert d["FS_EKF_THRESH"].type == ParamType.FLOAT and d["FS_EKF_THRESH"].default == 0.8  # values 0.6, 0.8, 1


def test_the_loader_is_firmware_neutral_and_refuses_a_bad_table(tmp_path: Path) -> None:
    p = tmp_path / "t.tsv"
    p.write_text(
        "# Some firmware 1.0\nname\ttype\tdefault\tmin\tmax\tunit\tflags\nA_B\ti\t3\t0\t5\t\tr\nC\tf\t0.5\t\t\tm\t-\n"
    )
    t = load_param_table(p)
    assert [d.name for d in t.defs] == ["A_B", "C"] and t.defs[0].type == ParamType.INT32 and t.defs[1].unit == "m"
    assert t.ranges == {"A_B": (0.0, 5.0)} and t.read_only == {"A_B"} and t.source == "Some firmware 1.0"
    assert t.defs[1].min == -math.inf  # limits are the personality's business
    bad = tmp_path / "bad.tsv"
    bad.write_text("name\ttype\nA\ti\n")
    with pytest.raises(ScenarioError, match="columns"):
        load_param_table(bad)
    bad.write_text("name\ttype\tdefault\tmin\tmax\tunit\tflags\nA\ti\t0.5\t\t\t\t-\n")
    with pytest.raises(ScenarioError, match=r"integer parameter A has the default 0\.5"):
        load_param_table(bad)


def test_stored_parameters_take_any_finite_value_as_arducopter_does() -> None:
    _core, ap = _copter()
    assert len(ap) > 1000
    assert ap.set("RC1_MIN", 5000).ok and ap["RC1_MIN"] == 5000.0  # outside 800..2200: ArduCopter keeps it too
    assert ap.set("PILOT_THR_BHV", 2.9999).ok and ap.get("PILOT_THR_BHV") == 3  # AP_Param::set_float's +0.01
    assert ap.set("PILOT_THR_BHV", 2.5).ok and ap.get("PILOT_THR_BHV") == 2
    assert stored_value(ParamType.INT32, -1.995) == -2.0 and stored_value(ParamType.INT32, 1e12) == 2147483647.0
    assert not ap.set("RC1_MAX", math.nan).ok and ap["RC1_MAX"] == 1900.0
    r = ap.set("FORMAT_VERSION", 3)
    assert not r.ok and r.reason == "Param write denied (FORMAT_VERSION)"


def test_flown_parameters_keep_arducopters_documented_limits() -> None:
    core, ap = _copter()
    assert not ap.set("WPNAV_SPEED", 15).ok  # ArduCopter 4.2: 20..2000 cm/s
    assert ap.set("WPNAV_SPEED", 20).ok and core["MPC_XY_CRUISE"] == 3.0  # the core flies its lowest
    assert ap.set("WPNAV_SPEED_UP", 1000).ok and core["MPC_Z_VEL_MAX_UP"] == 8.0
    assert not ap.set("WPNAV_SPEED_UP", 1001).ok


def test_a_personalitys_table_is_saved_per_vehicle_and_restored(tmp_path: Path) -> None:
    _core, ap = _copter()
    persist_params(ap, tmp_path, 2, "ardupilot")
    assert ap.set("RC_OVERRIDE_TIME", 1.5).ok and ap.set("WPNAV_SPEED", 800).ok
    path = store_path(tmp_path, 2, "ardupilot")
    assert path.name == "vehicle-2-ardupilot.json" and path.is_file()
    core2, again = _copter()
    assert persist_params(again, tmp_path, 2, "ardupilot") == []
    assert again["RC_OVERRIDE_TIME"] == 1.5 and again["WPNAV_SPEED"] == 800.0 and core2["MPC_XY_CRUISE"] == 8.0


def test_arducopter_3_names_dronekits_examples_use_share_a_core_parameter() -> None:
    core, ap = _copter()
    assert ap.set("THR_MID", 400).ok and core["MPC_THR_HOVER"] == 0.4 and ap["MOT_THST_HOVER"] == 0.4
    assert ap.set("MOT_THST_HOVER", 0.5).ok and ap["THR_MID"] == 500.0
    assert core.set("MPC_THR_HOVER", 0.45).ok and ap["THR_MID"] == 450.0 and ap["MOT_THST_HOVER"] == 0.45
