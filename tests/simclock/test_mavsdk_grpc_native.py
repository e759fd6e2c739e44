"""The gRPC API on the native core (``harness.simclock.mavsdk_grpc_*``), without a vehicle: the mapping of every
plugin the gRPC ``System`` exposes, the conversions field by field, errors and streams through the gRPC API's own
plugin classes on a native channel whose native plugins are fakes."""

from __future__ import annotations

import asyncio
import enum
import importlib
import inspect
import math
import os
import re
import subprocess
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("mavsdk_grpc")
pytest.importorskip("mavsdk.asyncio")

from google.protobuf import descriptor_pool
from mavsdk_grpc import action as g_action
from mavsdk_grpc import calibration as g_calibration
from mavsdk_grpc import core as g_core
from mavsdk_grpc import mission as g_mission
from mavsdk_grpc import mission_pb2
from mavsdk_grpc import offboard as g_offboard
from mavsdk_grpc import telemetry as g_telemetry
from mavsdk_grpc.system import System as GrpcSystem

from harness.simclock import mavsdk_grpc_channel as ch
from harness.simclock import mavsdk_grpc_mapping as mp
from harness.simclock import mavsdk_grpc_native as gn

NATIVE = mp.load_native()
PLUGINS = gn.grpc_plugins(GrpcSystem)


def services(plugin: str) -> list[Any]:
    pb = importlib.import_module(f"mavsdk_grpc.{plugin}_pb2")
    return list(pb.DESCRIPTOR.services_by_name.values())


def public_methods(cls: type) -> dict[str, str]:
    """Each public method of a gRPC plugin class → the RPC it calls (``self._stub.X``)."""
    out = {}
    for name, fn in vars(cls).items():
        if name.startswith("_") or not callable(fn):
            continue
        rpcs = re.findall(r"self\._stub\.(\w+)\(", inspect.getsource(fn))
        assert len(rpcs) == 1, f"{cls.__name__}.{name} calls {rpcs}"
        out[name] = rpcs[0]
    return out


# ------------------------------------------------------------------------------------------- mapping coverage


def test_the_grpc_system_exposes_the_plugins_we_map() -> None:
    assert {"action", "telemetry", "mission", "mission_raw", "offboard", "param", "core", "follow_me"} <= set(PLUGINS)
    assert len(PLUGINS) == 38  # every plugin of mavsdk-grpc 4.0.5; a new one must be looked at


@pytest.mark.parametrize("plugin", sorted(PLUGINS))
def test_every_public_grpc_method_maps_to_a_native_one_or_is_declared_unavailable(plugin: str) -> None:
    """Unary RPC ``Foo`` → native ``foo(request fields…)``; stream ``SubscribeFoo`` → native async generator
    ``subscribe_foo`` (or ``foo``); or hand-written alike (``fn(backend, request fields…)``); or listed in
    ``NOT_AVAILABLE`` with the reason."""
    methods = public_methods(PLUGINS[plugin])
    assert methods, plugin
    descs = {m.name: m for s in services(plugin) for m in s.methods}
    native_cls = mp.plugin_class(NATIVE, plugin)
    for public, rpc in methods.items():
        desc = descs[rpc]
        if ch.not_available(plugin, rpc):
            continue
        fn = ch.HAND_WRITTEN.get(f"{plugin}.{rpc}")
        if fn is None:
            assert native_cls is not None, f"{plugin}: no native plugin and not declared unavailable"
            name = ch.native_method_name(native_cls, rpc, desc.server_streaming)
            assert name is not None, f"{plugin}.{public}() ({rpc}) has no native counterpart"
            fn = getattr(native_cls, name)
        kind = inspect.isasyncgenfunction if desc.server_streaming else inspect.iscoroutinefunction
        assert kind(fn), f"{plugin}.{fn.__name__}: not a {kind.__name__}"
        params = list(inspect.signature(fn).parameters)[1:]  # after self, or a hand-written RPC's backend
        assert params == [f.name for f in desc.input_type.fields], f"{plugin}.{public}: {params}"


def test_what_is_not_available_is_named_and_explained() -> None:
    for key, why in ch.NOT_AVAILABLE.items():
        plugin, rpc = key.split(".")
        assert plugin in PLUGINS and why
        if rpc != "*":
            assert rpc in {m.name for s in services(plugin) for m in s.methods}
    # the whole-plugin entries really have no native plugin; the rest of core is served here
    assert mp.plugin_class(NATIVE, "tracking_server") is None
    assert mp.plugin_class(NATIVE, "component_metadata_server") is None
    assert "core.SubscribeConnectionState" in ch.HAND_WRITTEN
    # and the native bindings worked around (tune.play_tune: its C struct is declared wrong)
    for key in ch.HAND_WRITTEN:
        plugin, rpc = key.split(".")
        assert rpc in {m.name for s in services(plugin) for m in s.methods}


def test_the_tune_binding_is_still_broken_else_drop_the_work_around() -> None:
    tune = NATIVE.types["tune"]
    with pytest.raises(TypeError):
        tune.TuneDescription([tune.SongElement.NOTE_A], 120).to_c_struct()


def _all_enums_and_messages() -> tuple[list[Any], list[Any]]:
    enums: list[Any] = []
    messages: list[Any] = []

    def walk(msg: Any) -> None:
        messages.append(msg)
        enums.extend(msg.enum_types)
        for nested in msg.nested_types:
            walk(nested)

    for plugin in PLUGINS:
        if ch.not_available(plugin, "*") or plugin == "core":  # core: served here, no native plugin
            continue
        pb = importlib.import_module(f"mavsdk_grpc.{plugin}_pb2")
        enums.extend(pb.DESCRIPTOR.enum_types_by_name.values())
        for msg in pb.DESCRIPTOR.message_types_by_name.values():
            walk(msg)
    return enums, messages


def test_every_enum_maps_by_name_both_ways() -> None:
    enums, _ = _all_enums_and_messages()
    assert len(enums) > 50
    for e in enums:
        cls = mp.native_type(NATIVE, e.full_name)
        assert issubclass(cls, enum.Enum), e.full_name
        for v in e.values:
            native = mp.enum_to_native(NATIVE, e, v.number)
            assert mp.enum_to_pb(e, native) == v.number, (e.full_name, v.name)


def test_every_data_message_has_a_native_class_with_its_fields() -> None:
    _, messages = _all_enums_and_messages()
    checked = 0
    for m in messages:
        if m.name.endswith(("Request", "Response")) or mp.result_field(m) is not None:
            continue
        if m.name.endswith("Result") and "result" in m.fields_by_name:
            continue  # results travel as the native result enums
        obj = mp.native_type(NATIVE, m.full_name)()
        missing = [f.name for f in m.fields if not hasattr(obj, f.name)]
        assert not missing, f"{m.full_name}: native {type(obj).__name__} lacks {missing}"
        checked += 1
    assert checked > 100


# ------------------------------------------------------------------------------------------- conversions


def mission_plan() -> g_mission.MissionPlan:
    item = g_mission.MissionItem
    return g_mission.MissionPlan(
        [
            item(
                47.39, 8.54, 10.0, 5.0, True, -90.0, 0.0,
                item.CameraAction.TAKE_PHOTO, 2.5, 1.0, 0.5, 90.0, 3.0, item.VehicleAction.TAKEOFF,
            ),
            item(
                47.40, 8.55, 20.0, float("nan"), False, float("nan"), float("nan"),
                item.CameraAction.NONE, float("nan"), 1.0, float("nan"), float("nan"), float("nan"),
                item.VehicleAction.LAND,
            ),
        ]
    )  # fmt: skip


def test_mission_plan_round_trip_field_by_field() -> None:
    plan = mission_plan()
    pb = mission_pb2.MissionPlan()
    plan.translate_to_rpc(pb)
    native = mp.message_to_native(NATIVE, pb)
    nm = NATIVE.types["mission"]
    assert isinstance(native, nm.MissionPlan) and len(native.mission_items) == 2
    first = native.mission_items[0]
    assert isinstance(first, nm.MissionItem)
    assert first.camera_action is nm.MissionItem.CameraAction.TAKE_PHOTO
    assert first.vehicle_action is nm.MissionItem.VehicleAction.TAKEOFF
    assert (first.latitude_deg, first.relative_altitude_m, first.is_fly_through) == (47.39, 10.0, True)
    assert math.isnan(native.mission_items[1].speed_m_s)
    back = mission_pb2.MissionPlan()
    mp.native_to_message(native, back)
    again = g_mission.MissionPlan.translate_from_rpc(back)
    for a, b in zip(plan.mission_items, again.mission_items, strict=True):
        for name in vars(a):
            x, y = getattr(a, name), getattr(b, name)
            assert x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y)), name


def test_offboard_setpoint_reaches_the_native_method_as_its_class() -> None:
    seen: list[Any] = []

    class OffboardAsync:
        async def set_velocity_body(self, velocity_body_yawspeed: Any) -> None:
            seen.append(velocity_body_yawspeed)

    drone = fake_drone({"offboard": OffboardAsync()})
    asyncio.run(drone.offboard.set_velocity_body(g_offboard.VelocityBodyYawspeed(1.0, -2.0, 0.5, 30.0)))
    (v,) = seen
    assert isinstance(v, NATIVE.types["offboard"].VelocityBodyYawspeed)
    assert (v.forward_m_s, v.right_m_s, v.down_m_s, v.yawspeed_deg_s) == (1.0, -2.0, 0.5, 30.0)


# ------------------------------------------------------------------------------------------- through the gRPC API


def fake_drone(plugins: dict[str, Any]) -> Any:
    """A gRPC ``System`` whose plugins run on a native channel with the given fake native plugins."""
    backend = ch.Backend(NATIVE, None, None)
    backend._plugins.update(plugins)
    manager = gn._PluginManager(ch.NativeChannel(backend))
    drone = GrpcSystem.__new__(GrpcSystem)
    drone._plugins = {name: cls(manager) for name, cls in PLUGINS.items()}
    drone._server_process = None
    return drone


def test_unary_success_and_native_errors_become_the_grpc_error() -> None:
    na = NATIVE.types["action"]
    calls: list[str] = []

    class ActionAsync:
        async def arm(self) -> None:
            calls.append("arm")

        async def takeoff(self) -> None:
            raise na.ActionError(na.ActionResult.COMMAND_DENIED, "takeoff()")

        async def get_takeoff_altitude(self) -> float:
            return 12.5

    drone = fake_drone({"action": ActionAsync()})

    async def run() -> None:
        await drone.action.arm()
        assert await drone.action.get_takeoff_altitude() == 12.5
        with pytest.raises(g_action.ActionError) as err:
            await drone.action.takeoff()
        assert err.value._result.result is g_action.ActionResult.Result.COMMAND_DENIED
        assert err.value._origin == "takeoff()"  # the gRPC API's own error, raised by its own code
        assert "COMMAND_DENIED" in str(err.value)

    asyncio.run(run())
    assert calls == ["arm"]


def test_streams_yield_the_grpc_types_and_end_the_native_subscription() -> None:
    nt = NATIVE.types["telemetry"]
    closed: list[str] = []

    class TelemetryAsync:
        async def subscribe_flight_mode(self) -> AsyncIterator[Any]:
            try:
                for mode in (nt.FlightMode.HOLD, nt.FlightMode.MISSION):
                    yield mode
                await asyncio.sleep(3600)
            finally:
                closed.append("flight_mode")

        async def subscribe_position(self) -> AsyncIterator[Any]:
            yield nt.Position(47.39, 8.54, 500.0, 10.0)

    drone = fake_drone({"telemetry": TelemetryAsync()})

    async def run() -> None:
        modes = []
        stream = drone.telemetry.flight_mode()
        async for mode in stream:
            modes.append(mode)
            if len(modes) == 2:
                break
        await stream.aclose()
        await asyncio.sleep(0)
        await asyncio.sleep(0)
        assert modes == [g_telemetry.FlightMode.HOLD, g_telemetry.FlightMode.MISSION]
        async for pos in drone.telemetry.position():
            assert isinstance(pos, g_telemetry.Position)
            assert (pos.latitude_deg, pos.relative_altitude_m) == (47.39, 10.0)
            break

    asyncio.run(run())
    assert closed == ["flight_mode"]


def test_progress_streams_report_and_their_failure_raises_the_grpc_error() -> None:
    nc = NATIVE.types["calibration"]

    class CalibrationAsync:
        async def calibrate_gyro(self) -> AsyncIterator[Any]:
            yield nc.CalibrationResult.NEXT, nc.ProgressData(True, 0.5, False, "")
            raise nc.CalibrationError(nc.CalibrationResult.TIMEOUT, "calibrate_gyro()")

    drone = fake_drone({"calibration": CalibrationAsync()})

    async def run() -> list[float]:
        seen = []
        with pytest.raises(g_calibration.CalibrationError) as err:
            async for progress in drone.calibration.calibrate_gyro():
                seen.append(progress.progress)
        assert err.value._result.result is g_calibration.CalibrationResult.Result.TIMEOUT
        return seen

    assert asyncio.run(run()) == [0.5]


def test_connection_state_sends_the_current_state_first() -> None:
    class RawSystem:
        def __init__(self) -> None:
            self.callbacks: list[Any] = []

        def is_connected(self) -> bool:
            return True

        def subscribe_is_connected(self, cb: Any) -> int:
            self.callbacks.append(cb)
            return 7

        def unsubscribe_is_connected(self, handle: int) -> None:
            assert handle == 7
            self.callbacks.clear()

    class SystemAsync:
        _system = RawSystem()

    drone = fake_drone({})
    drone._plugins["core"]._stub.SubscribeConnectionState._channel.backend.system = SystemAsync()

    async def run() -> g_core.ConnectionState:
        async for state in drone.core.connection_state():
            return state
        raise AssertionError("no state")

    state = asyncio.run(run())
    assert isinstance(state, g_core.ConnectionState) and state.is_connected


@pytest.mark.parametrize(
    ("plugin", "call"),
    [
        ("core", lambda d: d.core.set_mavlink_timeout(2.0)),
        ("tracking_server", lambda d: d.tracking_server.set_tracking_off_status()),
    ],
)
def test_what_the_native_core_lacks_fails_at_call_time_naming_it(plugin: str, call: Any) -> None:
    drone = fake_drone({})
    with pytest.raises(mp.NotAvailableNatively, match=rf"{plugin}\.\w+\(\).*HARNESS_MAVSDK_GRPC=server"):
        asyncio.run(call(drone))


def test_every_rpc_path_resolves_in_the_descriptor_pool() -> None:
    pool = descriptor_pool.Default()
    for plugin in PLUGINS:
        for s in services(plugin):
            assert pool.FindServiceByName(s.full_name) is s


@pytest.mark.parametrize("backend", ["native", "server"])
def test_install_gives_the_script_the_grpc_api_on_the_chosen_backend(tmp_path: Path, backend: str) -> None:
    """In a fresh interpreter, as a mission: ``import mavsdk`` is the gRPC API, whose System runs on the native
    core (whose own modules were kept aside) or, with ``HARNESS_MAVSDK_GRPC=server``, on mavsdk_server."""
    script = tmp_path / "old.py"
    script.write_text("from mavsdk import System\n")
    probe = f"""
import sys
from pathlib import Path
from harness.simclock import mavsdk_compat, mavsdk_grpc_mapping as mp
assert mavsdk_compat.install(Path({str(script)!r}), None) == "grpc"
import mavsdk, mavsdk.telemetry
from mavsdk import System
assert mavsdk.__name__ == "mavsdk_grpc" and mavsdk.telemetry.__name__ == "mavsdk_grpc.telemetry"
native = getattr(System, "_harness_native", False)
server = getattr(System, "_harness_patched", False)
print("native" if native and not server else "server" if server and not native else "both?")
if native:
    assert hasattr(mp._native.mavsdk, "Mavsdk") and "telemetry" in mp._native.plugins
"""
    env = {**os.environ, "HARNESS_MAVSDK_GRPC": backend}
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == backend
