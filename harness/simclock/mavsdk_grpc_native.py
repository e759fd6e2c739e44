"""MAVSDK's old gRPC API (``mavsdk_grpc``) on the native MAVSDK core, in the mission's own process: its ``System``.

A script written for MAVSDK-Python's gRPC API (``System()``, ``await drone.connect()``, ``drone.action.arm()``)
normally talks gRPC to a ``mavsdk_server`` process whose threads run on the wall clock. Here the same script runs
unmodified on the native ``mavsdk`` ≥ 4 core (``libcmavsdk.so`` through ``mavsdk.asyncio``) in the mission
process, with no ``mavsdk_server`` and no gRPC traffic at all. Every line of the gRPC API's own code still runs
(argument checks, its result checks and error classes with their ``origin``, ``translate_from_rpc`` to its
classes and enums); only the transport changes. Three parts, bottom up:

- :mod:`.mavsdk_grpc_mapping`: the native package and the derived mapping of types and values (protobuf
  messages, enums and results ↔ the native classes);
- :mod:`.mavsdk_grpc_channel`: the calls, a channel whose RPCs call the native asyncio plugins, which the
  gRPC API's plugin classes build their stubs on;
- here: ``mavsdk_grpc.System`` patched (:func:`install`) so that ``connect()`` starts a native ``Mavsdk``
  configured as mavsdk_server configures its own, waits for the autopilot as mavsdk_server does before it
  serves, and gives the System's plugins that channel.

Loaded before the script's ``import mavsdk`` is redirected to ``mavsdk_grpc``
(:func:`~.mavsdk_grpc_mapping.load_native`): the native package's modules are kept aside, so both APIs live in
one process although both are called ``mavsdk``.
"""

from __future__ import annotations

import asyncio
import importlib
import inspect
import logging
from collections.abc import Callable
from typing import Any

from harness.simclock.mavsdk_grpc_channel import Backend, NativeChannel
from harness.simclock.mavsdk_grpc_mapping import Native, NotAvailableNatively, load_native

log = logging.getLogger(__name__)

DEFAULT_URL = "udpin://0.0.0.0:14540"
"""What ``System.connect()`` listens on without an address (as mavsdk_server)."""

PHASE_S = 0.02
"""A phase-0 period at the shipped rates: what was asked in one phase has been answered and read by the next."""


class _PluginManager:
    """What the gRPC API's plugins take (``AsyncPluginManager``): only its ``channel`` is used."""

    def __init__(self, channel: NativeChannel) -> None:
        self.channel = channel
        self.plugins: dict[str, Any] = {}


def grpc_plugins(system_cls: type) -> dict[str, type]:
    """The plugins the gRPC ``System`` exposes (its properties), by name, with their classes."""
    out: dict[str, type] = {}
    for name, prop in vars(system_cls).items():
        if isinstance(prop, property) and prop.fget is not None:
            cls = inspect.get_annotations(prop.fget, eval_str=True).get("return")
            if isinstance(cls, type):
                out[name] = cls
    return out


_alive: set[Backend] = set()
"""Every backend until :func:`_release`: the gRPC API's plugins, their channel and the backend reference each
other, and when the garbage collector frees such a cycle it clears weak references before finalizers run, so the native
``Mavsdk.__del__`` would find no systems to release first and ``mavsdk_destroy`` aborts the process ("A System
… must not outlive the Mavsdk instance"; seen with MAVSDK's logfile_download.py at its end)."""


def _release(backend: Backend) -> None:
    _alive.discard(backend)
    backend.destroy()


async def start_backend(native: Native, url: str, sysid: int, compid: int) -> Backend:
    """A native Mavsdk configured as mavsdk_server configures its own (a ground station with the System's
    ``sysid``/``compid``, 245/190 by default), connected to ``url``, with its first autopilot.

    Waits for the autopilot as mavsdk_server does before it serves (without a time limit). The wait blocks in
    the native core on an executor thread, like every blocking call of ``mavsdk.asyncio``."""
    m = native.mavsdk
    config = m.Configuration.create_with_component_type(m.ComponentType.GROUND_STATION)
    config.system_id = sysid
    config.component_id = compid
    mavsdk_async = native.asyncio.Mavsdk(config)
    try:
        await mavsdk_async.add_any_connection(url)
    except Exception as e:
        # mavsdk_server logs the failed connection and exits, and the gRPC API's connect() then waits for a
        # server that never answers (a script's asyncio.wait_for(drone.connect(...), 8) times out after 8 s)
        log.error("mavsdk_server: connection to %s failed (%s); connect() waits for a server that is not there", url, e)
        mavsdk_async.destroy()
        await asyncio.get_running_loop().create_future()
    loop = asyncio.get_running_loop()
    raw = await loop.run_in_executor(None, mavsdk_async._mavsdk.first_autopilot, -1.0)
    if raw is None:  # pragma: no cover - a negative time-out waits forever
        raise ConnectionError(f"no autopilot on {url}")
    # MAVSDK asks the new autopilot for its version as it finds it; the plugins made next ask only for what
    # is still missing. A phase on, that answer is read whatever the order of this thread and MAVSDK's within
    # the phase (made at once, the Info plugin asked again in 1 of 3 runs: another byte stream, same flight)
    await asyncio.sleep(PHASE_S)
    backend = Backend(native, mavsdk_async, native.asyncio.System(raw))
    _alive.add(backend)
    return backend


async def _version_known(backend: Backend, tries: int = 50, every_s: float = PHASE_S) -> None:
    """Wait (sim time, at most ``tries`` × ``every_s``) until the autopilot's version has come, as mavsdk_server
    has it by the time a script calls ``info.get_version()`` after connecting (MAVSDK-Python's
    firmware_version.py does so at once). The native Info plugin asks for it when it is made; made at the
    script's first call, it answered INFORMATION_NOT_RECEIVED_YET."""
    try:
        info = backend.plugin("info")
    except NotAvailableNatively:
        return
    for _ in range(tries):
        # look after a phase, never in the phase the request went out in: whether its answer had been read by
        # then depended on the order of this thread and MAVSDK's (in 1 of 3 runs the script's next requests went
        # out a phase later); a phase on, the answer of the last one is read, whatever that order
        await asyncio.sleep(every_s)
        try:
            await info.get_version()
            return
        except Exception:
            pass
    log.debug("mavsdk (gRPC API on the native core): the autopilot sent no version within %.1f s", tries * every_s)


def install(rewrite_url: Callable[[str], str]) -> None:
    """Make ``mavsdk_grpc.System`` run on the native core (idempotent). ``rewrite_url`` points a script's
    connection URL at its vehicle (``mavsdk_compat._for_vehicle``)."""
    native = load_native()
    system_mod = importlib.import_module("mavsdk_grpc.system")
    System = system_mod.System
    if getattr(System, "_harness_native", False):
        return
    plugins = grpc_plugins(System)
    orig_init: Callable[..., None] = System.__init__

    def __init__(
        self: Any,
        mavsdk_server_address: str | None = None,
        port: int = 50051,
        sysid: int = 245,
        compid: int = 190,
    ) -> None:
        if mavsdk_server_address is not None or port != 50051:
            log.debug(
                "mavsdk (gRPC API on the native core): mavsdk_server_address=%r, port=%r ignored (no mavsdk_server)",
                mavsdk_server_address,
                port,
            )
        orig_init(self, None, port, sysid, compid)
        self._harness_backend = None

    async def connect(self: Any, system_address: str | None = None) -> None:
        _stop_mavsdk_server(self)  # a second connect() starts afresh, as mavsdk_server's System does
        url = rewrite_url(system_address or DEFAULT_URL)
        log.info("mavsdk (gRPC API on the native core): connecting to %s", url)
        backend = await start_backend(native, url, self._sysid, self._compid)
        self._harness_backend = backend
        await _version_known(backend)
        manager = _PluginManager(NativeChannel(backend))
        self._plugins = {name: cls(manager) for name, cls in plugins.items()}

    def _stop_mavsdk_server(self: Any) -> None:
        """Release this System's native core (what stopping its mavsdk_server did)."""
        backend = getattr(self, "_harness_backend", None)
        if backend is not None:
            self._harness_backend = None
            _release(backend)

    System.__init__ = __init__
    System.connect = connect
    System._stop_mavsdk_server = _stop_mavsdk_server
    System._harness_native = True
