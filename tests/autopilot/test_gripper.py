"""The gripper service: MAV_CMD_DO_GRIPPER grabs and releases, the state shows in telemetry, bad instances and
actions are refused with a reason, and the ArduCopter personality shares the core's grippers."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as M

from harness.autopilot.api import Result
from harness.autopilot.autopilot import Autopilot
from harness.autopilot.mavlink.ardupilot.adapter import CopterSystem
from harness.autopilot.mavlink.ardupilot.params import CopterParams
from harness.autopilot.mavlink.commands import CommandIn, CommandService
from harness.autopilot.services import System


def _gripper_cmd(svc: CommandService, instance: float, action: float, now_ns: int) -> Result:
    cmd = CommandIn(M.MAV_CMD_DO_GRIPPER, (instance, action, 0.0, 0.0, 0.0, 0.0, 0.0))
    return svc.handle(cmd, ("gcs", now_ns), now_ns).result.result


def test_grab_and_release_show_in_telemetry() -> None:
    ap = Autopilot()
    assert ap.telemetry.state().grippers_grabbed == ()
    assert ap.gripper.grab(2).ok and ap.gripper.grab(1).ok and ap.gripper.grab(2).ok
    assert ap.telemetry.state().grippers_grabbed == (1, 2)
    assert ap.gripper.release(2).ok
    assert ap.telemetry.state().grippers_grabbed == (1,)
    refused = ap.gripper.grab(7)
    assert refused.result == Result.DENIED and "no gripper 7" in refused.reason


def test_do_gripper_is_accepted_and_kept() -> None:
    ap = Autopilot()
    svc = CommandService(ap, lambda _i: None, lambda _i, _v: True)
    assert _gripper_cmd(svc, 1, M.GRIPPER_ACTION_GRAB, 0) == Result.ACCEPTED
    assert ap.telemetry.state().grippers_grabbed == (1,)
    assert _gripper_cmd(svc, 1, M.GRIPPER_ACTION_RELEASE, 1) == Result.ACCEPTED
    assert ap.telemetry.state().grippers_grabbed == ()
    assert _gripper_cmd(svc, 1, 5, 2) == Result.DENIED  # no such GRIPPER_ACTIONS value
    assert _gripper_cmd(svc, 0, M.GRIPPER_ACTION_GRAB, 3) == Result.DENIED  # instances are 1..6
    assert _gripper_cmd(svc, 1.5, M.GRIPPER_ACTION_GRAB, 4) == Result.DENIED
    assert ap.telemetry.state().grippers_grabbed == ()


def test_ardupilot_personality_shares_the_core_gripper() -> None:
    core = Autopilot()
    copter: System = CopterSystem(core, CopterParams(core.params, 1))
    svc = CommandService(copter, lambda _i: None, lambda _i, _v: True)
    assert _gripper_cmd(svc, 1, M.GRIPPER_ACTION_GRAB, 0) == Result.ACCEPTED
    assert copter.telemetry.state().grippers_grabbed == core.telemetry.state().grippers_grabbed == (1,)


def test_a_system_without_a_gripper_answers_unsupported() -> None:
    core = Autopilot()
    without = CopterSystem(core, CopterParams(core.params, 1))
    without.gripper = None
    svc = CommandService(without, lambda _i: None, lambda _i, _v: True)
    assert _gripper_cmd(svc, 1, M.GRIPPER_ACTION_GRAB, 0) == Result.UNSUPPORTED
    assert core.telemetry.state().grippers_grabbed == ()
