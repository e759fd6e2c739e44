"""MAVSDK in mission processes: both APIs, and every script pointed at its own vehicle.

- The native ``mavsdk`` ≥ 4 (ctypes) and the old gRPC API both run unmodified. An old script does
  ``from mavsdk import System`` and ``await drone.connect(...)``; with ``mavsdk`` 4 installed that
  name belongs to the new API, so for such a script the runner makes ``mavsdk`` (and ``mavsdk.<plugin>``)
  resolve to ``mavsdk_grpc`` (PyPI ``mavsdk-grpc``), which is the old API under a new name.
- Scripts written for one vehicle listen on the standard port 14540 (``udpin://0.0.0.0:14540``,
  ``udp://:14540``). The runner points them at the vehicle's own port instead (``udpout://127.0.0.1:P``,
  :mod:`harness.core.endpoints`), so one unmodified script flies every vehicle of a swarm, and no
  other run's script can reach this run's vehicles.
- The gRPC API starts a ``mavsdk_server`` per ``System()`` on gRPC port 50051 by default; with several
  missions on one machine those collide, so the default becomes a free port.
"""

from __future__ import annotations

import enum
import importlib
import importlib.abc
import importlib.machinery
import logging
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

from harness.core.endpoints import VehicleEndpoints, mavsdk_url
from harness.core.freeport import free_tcp_port

log = logging.getLogger(__name__)


class MavsdkApi(enum.StrEnum):
    """Which MAVSDK a script uses (the value is what ``HARNESS_MAVSDK_API`` may force)."""

    NONE = ""
    NATIVE = "native"
    """mavsdk >= 4 (``Mavsdk()``, ``mavsdk.asyncio``)."""
    GRPC = "grpc"
    """The old gRPC API, imported as ``mavsdk``."""
    GRPC_NAMED = "grpc-named"
    """The old gRPC API, imported as ``mavsdk_grpc``."""


def detect_api(source: str) -> MavsdkApi:
    """GRPC for scripts written against the old API, NATIVE for mavsdk >= 4, NONE without MAVSDK."""
    if "mavsdk" not in source:
        return MavsdkApi.NONE
    if re.search(r"\bMavsdk\s*\(|mavsdk\.asyncio|Configuration\s*\(", source):
        return MavsdkApi.NATIVE
    if re.search(r"\bimport\s+mavsdk_grpc\b|from\s+mavsdk_grpc\b", source):
        return MavsdkApi.GRPC_NAMED
    return MavsdkApi.GRPC


class _AliasFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Resolves ``mavsdk`` and ``mavsdk.X`` to ``mavsdk_grpc`` and ``mavsdk_grpc.X``."""

    def find_spec(self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None) -> Any:
        if fullname == "mavsdk" or fullname.startswith("mavsdk."):
            return importlib.machinery.ModuleSpec(fullname, self)
        return None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        return importlib.import_module("mavsdk_grpc" + spec.name[len("mavsdk") :])

    def exec_module(self, module: ModuleType) -> None:
        pass


def _patch_grpc(ep: VehicleEndpoints | None) -> None:
    from harness.simclock.installed import current

    system_mod = importlib.import_module("mavsdk_grpc.system")
    System = system_mod.System
    if getattr(System, "_harness_patched", False):
        return
    orig_init: Callable[..., None] = System.__init__
    orig_connect = System.connect

    def __init__(
        self: Any, mavsdk_server_address: str | None = None, port: int | None = None, *a: Any, **kw: Any
    ) -> None:
        if port is None or (port == 50051 and mavsdk_server_address is None):
            port = free_tcp_port()
        orig_init(self, mavsdk_server_address, port, *a, **kw)

    async def connect(self: Any, system_address: str | None = None) -> Any:
        url = system_address or "udpin://0.0.0.0:14540"
        url = _for_vehicle(url, ep)
        log.info("mavsdk (gRPC API): connecting to %s", url)
        rt = current()
        if rt is None or not rt._tracked():
            return await orig_connect(self, system_address=url)
        rt.hold()  # starting mavsdk_server and discovering the vehicle take no sim time (as a request does)
        try:
            return await orig_connect(self, system_address=url)
        finally:
            rt.unhold()

    System.__init__ = __init__
    System.connect = connect
    System._harness_patched = True
    _hold_phase_during_requests()


STREAM_SETUP_HOLD_NS = 20_000_000
"""A new telemetry stream (a server-streaming gRPC call) keeps phase 0 open this long (wall clock), so that
mavsdk_server has registered the subscription before the sim moves on. It gives no signal when it has;
without the hold, a loaded machine let it register after the next message of a slow stream, and the script
waited for the one after (HOME_POSITION at 0.5 Hz: ``mission_rtl.py`` lifted off 2.00 s later in one run of
three)."""


def _hold_phase_during_requests() -> None:
    """A MAVSDK request (arm, takeoff, set a setpoint, upload a mission: every unary gRPC call to
    mavsdk_server) keeps the script's phase 0 open until its answer is back, so it takes no sim time.

    mavsdk_server answers on the wall clock once the autopilot has acknowledged (the autopilot's MAVLink
    side answers within milliseconds of wall time, whatever the sim does). Without the hold, the sim would
    run on while the request travels — at x50 a 20 ms round trip is a whole second of sim time, so an
    offboard stop or a mode change would take effect at a place that depends on the machine's speed.
    Streams (telemetry subscriptions) wait for the sim; only their start holds the phase, for
    ``STREAM_SETUP_HOLD_NS`` of wall time.
    """
    from grpc.aio import _channel

    from harness.simclock.installed import current

    callable_cls: Any = _channel.UnaryUnaryMultiCallable
    if getattr(callable_cls, "_harness_holds", False):
        return
    orig_call = callable_cls.__call__

    def __call__(self: Any, *a: Any, **kw: Any) -> Any:
        call = orig_call(self, *a, **kw)
        rt = current()
        if rt is not None and rt._tracked():
            rt.hold()
            call.add_done_callback(lambda _call: rt.unhold())
        return call

    callable_cls.__call__ = __call__
    callable_cls._harness_holds = True

    stream_cls: Any = _channel.UnaryStreamMultiCallable
    orig_stream = stream_cls.__call__

    def subscribe(self: Any, *a: Any, **kw: Any) -> Any:
        call = orig_stream(self, *a, **kw)
        rt = current()
        if rt is not None and rt._tracked():
            rt.hold_for(STREAM_SETUP_HOLD_NS)
        return call

    stream_cls.__call__ = subscribe


def _patch_native(ep: VehicleEndpoints | None) -> None:
    for modname in ("mavsdk.mavsdk", "mavsdk.asyncio.mavsdk"):
        try:
            mod = importlib.import_module(modname)
        except ImportError:
            continue
        cls = getattr(mod, "Mavsdk", None)
        if cls is None or getattr(cls, "_harness_patched", False):
            continue
        for name in ("add_any_connection", "add_any_connection_with_handle"):
            orig = getattr(cls, name, None)
            if orig is None:
                continue
            setattr(cls, name, _wrap_connection(orig, ep))
        cls._harness_patched = True


def _wrap_connection(orig: Callable[..., Any], ep: VehicleEndpoints | None) -> Callable[..., Any]:
    def rewrite(url: str) -> str:
        return _for_vehicle(url, ep)

    import inspect

    if inspect.iscoroutinefunction(orig):

        async def async_wrapper(self: Any, url: str, *a: Any, **kw: Any) -> Any:
            return await orig(self, rewrite(url), *a, **kw)

        return async_wrapper

    def wrapper(self: Any, url: str, *a: Any, **kw: Any) -> Any:
        return orig(self, rewrite(url), *a, **kw)

    return wrapper


def install(script: Path, ep: VehicleEndpoints | None, api: MavsdkApi | None = None) -> MavsdkApi:
    """Prepare MAVSDK for ``script``; returns the API used (NATIVE, GRPC or NONE)."""
    source = script.read_text(errors="replace")
    api = api or detect_api(source)
    if api in (MavsdkApi.GRPC, MavsdkApi.GRPC_NAMED):
        try:
            importlib.import_module("mavsdk_grpc")
        except ImportError:
            from harness.core.errors import ScenarioError

            raise ScenarioError(
                f"{script} uses the old gRPC MAVSDK API (from mavsdk import System … await drone.connect()); "
                "install it with: pip install mavsdk-grpc"
            ) from None
        if api == MavsdkApi.GRPC:
            for name in [m for m in sys.modules if m == "mavsdk" or m.startswith("mavsdk.")]:
                del sys.modules[name]
            sys.meta_path.insert(0, _AliasFinder())
        _patch_grpc(ep)
        return MavsdkApi.GRPC
    if api == MavsdkApi.NATIVE:
        _patch_native(ep)
        return MavsdkApi.NATIVE
    return MavsdkApi.NONE


def _for_vehicle(url: str, ep: VehicleEndpoints | None) -> str:
    """``url`` as MAVSDK is to use it in a run: listening on a port announced to the mission's vehicle."""
    if ep is None:
        return url
    from harness.simclock.simsocket import announce_listen_port

    return mavsdk_url(url, ep, lambda: announce_listen_port(ep))
