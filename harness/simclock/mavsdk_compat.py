"""MAVSDK in mission processes: both APIs, and every script pointed at its own vehicle.

- The native ``mavsdk`` ≥ 4 (ctypes) and the old gRPC API both run unmodified. An old script does
  ``from mavsdk import System`` and ``await drone.connect(...)``; with ``mavsdk`` 4 installed that
  name belongs to the new API, so for such a script the runner makes ``mavsdk`` (and ``mavsdk.<plugin>``)
  resolve to ``mavsdk_grpc`` (PyPI ``mavsdk-grpc``), which is the old API under a new name.
- Scripts written for one vehicle listen on the standard port 14540 (``udpin://0.0.0.0:14540``,
  ``udp://:14540``). The runner points them at the vehicle's own port instead (``udpout://127.0.0.1:P``,
  :mod:`harness.core.endpoints`), so one unmodified script flies every vehicle of a swarm, and no
  other run's script can reach this run's vehicles.
- The gRPC API runs on the native MAVSDK core in the mission process (:mod:`.mavsdk_grpc_native`): no
  ``mavsdk_server``, no gRPC. ``HARNESS_MAVSDK_GRPC=server`` keeps MAVSDK-Python's own way, a ``mavsdk_server``
  per ``System()`` (on a free gRPC port: several missions on one machine would collide on 50051).
"""

from __future__ import annotations

import enum
import importlib
import importlib.abc
import importlib.machinery
import logging
import os
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

from harness.core.endpoints import VehicleEndpoints, mavsdk_url, team_mavsdk_url
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


GRPC_BACKEND_ENV = "HARNESS_MAVSDK_GRPC"
"""``server``: run gRPC-API scripts on ``mavsdk_server`` as MAVSDK-Python does (the comparison path); anything
else or unset: on the native core in the mission process (:mod:`harness.simclock.mavsdk_grpc_native`)."""


def grpc_backend() -> str:
    """``native`` (the default) or ``server`` (``HARNESS_MAVSDK_GRPC=server``)."""
    value = os.environ.get(GRPC_BACKEND_ENV, "").strip().lower()
    if value in ("", "native"):
        return "native"
    if value == "server":
        return "server"
    from harness.core.errors import ScenarioError

    raise ScenarioError(f"{GRPC_BACKEND_ENV}={value!r}: expected 'native' (default) or 'server'")


def _patch_grpc_server(ep: VehicleEndpoints | None) -> None:
    """The gRPC API on ``mavsdk_server`` (``HARNESS_MAVSDK_GRPC=server``): each ``System()`` on a free gRPC
    port (several missions on one machine would collide on 50051), its URL pointed at the vehicle."""
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
        url = _for_vehicle(system_address or "udpin://0.0.0.0:14540", ep)
        log.info("mavsdk (gRPC API, mavsdk_server): connecting to %s", url)
        return await orig_connect(self, system_address=url)

    System.__init__ = __init__
    System.connect = connect
    System._harness_patched = True


def on_sim_clock() -> bool:
    """Put MAVSDK's native core (``libcmavsdk.so``) on this mission's sim clock (``native.attach``).

    True when its threads now follow sim time; False without a runtime (outside a run), without a C compiler,
    or with ``HARNESS_MAVSDK_CLOCK=wall`` (the old behaviour, to compare against)."""
    from harness.simclock import native
    from harness.simclock.installed import current

    rt = current()
    if rt is None or os.environ.get("HARNESS_MAVSDK_CLOCK", "sim") == "wall":
        return False
    if native.attached("libcmavsdk"):
        return True
    importlib.import_module("mavsdk.cmavsdk_loader")  # loads libcmavsdk.so
    trace_dir = os.environ.get("HARNESS_SIMTIME_TRACE_DIR")
    if trace_dir:  # every release of MAVSDK's threads, per vehicle: for comparing two runs (docs/simclock.md)
        os.environ["HARNESS_SIMTIME_TRACE"] = os.path.join(trace_dir, f"simtime-{rt.vehicle}.trace")
    clock = native.attach("libcmavsdk", rt.epoch_ns, rt.now_ns())
    if clock is None:
        return False
    rt.native = clock
    return True


def _shim_unavailable() -> bool:
    """In a run, the sim-clock shim for MAVSDK's core cannot be built here (no C compiler)."""
    from harness.simclock import shim
    from harness.simclock.installed import current

    return current() is not None and os.environ.get("HARNESS_MAVSDK_CLOCK", "sim") != "wall" and shim.build() is None


def _patch_native(ep: VehicleEndpoints | None) -> None:
    on_sim_clock()
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
        backend = grpc_backend()
        if backend == "native":
            from harness.simclock import mavsdk_grpc_mapping

            mavsdk_grpc_mapping.load_native()  # before ``mavsdk`` becomes mavsdk_grpc for the script
            if not on_sim_clock() and _shim_unavailable():
                backend = "server"  # no C compiler: today's path, mavsdk_server with its holds (said once)
        if api == MavsdkApi.GRPC:
            for name in [m for m in sys.modules if m == "mavsdk" or m.startswith("mavsdk.")]:
                del sys.modules[name]
            sys.meta_path.insert(0, _AliasFinder())
        if backend == "server":
            _patch_grpc_server(ep)
        else:
            from harness.simclock import mavsdk_grpc_native

            mavsdk_grpc_native.install(lambda url: _for_vehicle(url, ep))
        return MavsdkApi.GRPC
    if api == MavsdkApi.NATIVE:
        _patch_native(ep)
        return MavsdkApi.NATIVE
    return MavsdkApi.NONE


def _for_vehicle(url: str, ep: VehicleEndpoints | None) -> str:
    """``url`` as MAVSDK is to use it in a run: listening on a port announced to the mission's vehicle."""
    from harness.simclock.installed import INSTALLED, current
    from harness.simclock.simsocket import announce_listen_port

    rt = current()
    sim = rt is not None and rt.native is not None
    if ep is None:  # a swarm mission: a URL of one of its vehicles listens on a port announced to that vehicle
        return team_mavsdk_url(url, INSTALLED.team, lambda member: announce_listen_port(member, sim_clock=sim))[0]
    return mavsdk_url(url, ep, lambda: announce_listen_port(ep, sim_clock=sim))
