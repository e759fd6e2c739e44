"""MAVSDK's old gRPC API (``mavsdk_grpc``) on the native MAVSDK core, in the mission's own process.

A script written for MAVSDK-Python's gRPC API (``System()``, ``await drone.connect()``, ``drone.action.arm()``)
normally talks gRPC to a ``mavsdk_server`` process whose threads run on the wall clock. Here the same script runs
unmodified on the native ``mavsdk`` ≥ 4 core (``libcmavsdk.so`` through ``mavsdk.asyncio``) in the mission
process, with no ``mavsdk_server`` and no gRPC traffic at all.

How: the gRPC API's plugin classes (``mavsdk_grpc.action.Action`` …) talk to a *stub* built on a gRPC channel
(``AsyncBase._setup_stub(channel)``). We hand them a :class:`NativeChannel` instead: each RPC
(``/mavsdk.rpc.action.ActionService/Arm``) becomes a call of the native asyncio plugin
(``mavsdk.asyncio.plugins.action.ActionAsync.arm``). So every line of the gRPC API's own code still runs
(argument checks, its result checks and error classes with their ``origin``, ``translate_from_rpc`` to its
classes and enums), and only the transport changes. The mapping is derived, not written per method:

- the plugin is the proto package (``mavsdk.rpc.<plugin>``), its native class the ``*Async`` class of
  ``mavsdk.asyncio.plugins.<plugin>``, built on the system (or on the server component, for ``*_server``
  plugins, whose native constructor takes ``server_component``);
- a unary RPC ``FooBar`` is the native ``foo_bar``; a server-streaming RPC ``SubscribeFooBar`` is the native
  async generator ``subscribe_foo_bar`` (or ``foo_bar``, for the progress streams: ``upload_mission_with_progress``,
  ``calibrate_gyro``, ftp ``download``);
- the request's fields, in order, are the native method's arguments: protobuf messages become the native
  classes of the same proto name (``mavsdk.plugins.<plugin>.<Name>``) field by field, recursively, lists too;
  enums go by value name (``FLIGHT_MODE_HOLD`` ↔ ``FlightMode.HOLD``);
- the native answer fills the response the same way: its one data field, and its ``<plugin>_result``, which is
  SUCCESS unless the native call raised the plugin's error (``ActionError(ActionResult.DENIED)``), whose result
  goes there instead, so the gRPC API raises its own error (``e._result.result``) as it did with mavsdk_server.

``core`` has no native plugin: its connection-state stream is the native system's ``is_connected`` (the current
state first, as mavsdk_server sends it). What the native core lacks (:data:`NOT_AVAILABLE`) raises
:class:`NotAvailableNatively` when called, naming the method.

Loaded before the script's ``import mavsdk`` is redirected to ``mavsdk_grpc`` (:func:`load_native`): the native
package's modules are kept here, so both APIs live in one process although both are called ``mavsdk``.
"""

from __future__ import annotations

import asyncio
import enum
import functools
import importlib
import inspect
import logging
import pkgutil
import re
import sys
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from types import ModuleType, SimpleNamespace
from typing import Any

log = logging.getLogger(__name__)

DEFAULT_URL = "udpin://0.0.0.0:14540"
"""What ``System.connect()`` listens on without an address (as mavsdk_server)."""

NOT_AVAILABLE: dict[str, str] = {
    "core.SetMavlinkTimeout": "the native core has no MAVLink time-out setting",
    "core.FeedHeartbeatWatchdog": "the native core has no heartbeat watchdog",
    "core.SetHeartbeatWatchdogTimeout": "the native core has no heartbeat watchdog",
    "component_metadata_server.*": "the native mavsdk 4.1.0 package fails to import this plugin",
    "tracking_server.*": "the native core has no tracking_server plugin",
}
"""gRPC methods (``plugin.Rpc``, or ``plugin.*`` for a whole plugin) without a native counterpart, and why."""


class NotAvailableNatively(RuntimeError):
    """A gRPC-API method the native MAVSDK core does not have (see ``HARNESS_MAVSDK_GRPC=server``)."""


def _snake(name: str) -> str:
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower()


def _upper_snake(name: str) -> str:
    return _snake(name).upper()


# -- the native package ------------------------------------------------------------------------------------


@dataclass
class Native:
    """The native ``mavsdk`` package's modules, kept apart from ``sys.modules`` (where a gRPC script's
    ``mavsdk`` is ``mavsdk_grpc``)."""

    mavsdk: ModuleType
    asyncio: ModuleType
    plugins: dict[str, ModuleType] = field(default_factory=dict)
    """``mavsdk.asyncio.plugins.<name>`` by plugin name."""
    types: dict[str, ModuleType] = field(default_factory=dict)
    """``mavsdk.plugins.<name>`` by plugin name."""
    broken: dict[str, str] = field(default_factory=dict)
    """Plugins whose native module does not import, with the error."""


_native: Native | None = None


def load_native() -> Native:
    """Import the native ``mavsdk`` and every plugin of it (≈ 0.1 s). Call before ``mavsdk`` is redirected."""
    global _native
    if _native is not None:
        return _native
    mod = sys.modules.get("mavsdk")
    if mod is not None and not hasattr(mod, "Mavsdk"):
        raise RuntimeError("load_native() after 'mavsdk' was redirected to mavsdk_grpc")
    masync = importlib.import_module("mavsdk.asyncio")
    native = Native(importlib.import_module("mavsdk"), masync)
    pkg = importlib.import_module("mavsdk.asyncio.plugins")
    for info in pkgutil.iter_modules(pkg.__path__):
        try:
            native.plugins[info.name] = importlib.import_module(f"mavsdk.asyncio.plugins.{info.name}")
            native.types[info.name] = importlib.import_module(f"mavsdk.plugins.{info.name}")
        except ImportError as e:
            native.broken[info.name] = str(e)
    _native = native
    return native


def plugin_class(native: Native, plugin: str) -> type | None:
    """The native asyncio class of ``plugin`` (``ActionAsync``), None if there is none."""
    mod = native.plugins.get(plugin)
    if mod is None:
        return None
    for name, obj in vars(mod).items():
        if name.endswith("Async") and isinstance(obj, type):
            return obj
    return None


# -- protobuf <-> native values ----------------------------------------------------------------------------


def _plugin_of(full_name: str) -> tuple[str, list[str]]:
    """``mavsdk.rpc.mission.MissionItem.CameraAction`` → (``mission``, [``MissionItem``, ``CameraAction``])."""
    parts = full_name.split(".")
    assert parts[:2] == ["mavsdk", "rpc"], full_name
    return parts[2], parts[3:]


def native_type(native: Native, full_name: str) -> Any:
    """The native class or enum of a proto message or enum (by its full proto name)."""
    plugin, path = _plugin_of(full_name)
    mod = native.types.get(plugin)
    if mod is None:
        raise NotAvailableNatively(f"no native type for {full_name}: plugin {plugin!r} is not in the native core")
    obj: Any = mod
    for i, part in enumerate(path):
        nxt = getattr(obj, part, None)
        if nxt is None:
            # the result enums: proto FooResult.Result is the native IntEnum FooResult
            if i == len(path) - 1 and part == "Result" and isinstance(obj, type) and issubclass(obj, enum.Enum):
                return obj
            raise NotAvailableNatively(f"no native type for {full_name}")
        obj = nxt
    return obj


def _enum_prefix(enum_desc: Any) -> str:
    return _upper_snake(enum_desc.name) + "_"


def enum_to_native(native: Native, enum_desc: Any, number: int) -> Any:
    cls = native_type(native, enum_desc.full_name)
    value = enum_desc.values_by_number.get(number)
    if value is None:
        return cls(number)
    name = value.name.removeprefix(_enum_prefix(enum_desc))
    return cls[name]


def enum_to_pb(enum_desc: Any, value: Any) -> int:
    if isinstance(value, enum.Enum):
        pb = enum_desc.values_by_name.get(_enum_prefix(enum_desc) + value.name)
        if pb is None:
            raise ValueError(f"{enum_desc.full_name} has no value for {value!r}")
        return int(pb.number)
    return int(value)


def message_to_native(native: Native, msg: Any) -> Any:
    """A protobuf message as the native class of the same proto name, field by field."""
    desc = msg.DESCRIPTOR
    obj = native_type(native, desc.full_name)()
    for f in desc.fields:
        setattr(obj, f.name, _field_to_native(native, f, getattr(msg, f.name)))
    return obj


def _field_to_native(native: Native, f: Any, value: Any) -> Any:
    if _is_repeated(f):
        return [_scalar_to_native(native, f, v) for v in value]
    return _scalar_to_native(native, f, value)


def _is_repeated(f: Any) -> bool:
    rep = getattr(f, "is_repeated", None)
    if rep is not None:
        return bool(rep)
    return bool(f.label == f.LABEL_REPEATED)


def _scalar_to_native(native: Native, f: Any, value: Any) -> Any:
    if f.message_type is not None:
        return message_to_native(native, value)
    if f.enum_type is not None:
        return enum_to_native(native, f.enum_type, value)
    return value


def native_to_message(value: Any, msg: Any) -> None:
    """Fill the protobuf message ``msg`` from the native object ``value`` (attributes by field name)."""
    for f in msg.DESCRIPTOR.fields:
        if not hasattr(value, f.name):
            continue
        set_field(msg, f, getattr(value, f.name))


def set_field(msg: Any, f: Any, value: Any) -> None:
    if value is None:
        return
    if _is_repeated(f):
        target = getattr(msg, f.name)
        for v in value:
            if f.message_type is not None:
                native_to_message(v, target.add())
            elif f.enum_type is not None:
                target.append(enum_to_pb(f.enum_type, v))
            else:
                target.append(_plain(f, v))
        return
    if f.message_type is not None:
        native_to_message(value, getattr(msg, f.name))
    elif f.enum_type is not None:
        setattr(msg, f.name, enum_to_pb(f.enum_type, value))
    else:
        setattr(msg, f.name, _plain(f, value))


def _plain(f: Any, value: Any) -> Any:
    if isinstance(value, enum.Enum):
        value = value.value
    if f.type == f.TYPE_BYTES and isinstance(value, str):
        return value.encode()
    if f.type == f.TYPE_STRING and isinstance(value, bytes):
        return value.decode(errors="replace")
    if f.type in (f.TYPE_FLOAT, f.TYPE_DOUBLE):
        return float(value)
    return value


# -- responses -------------------------------------------------------------------------------------------


def result_field(desc: Any) -> Any | None:
    """The ``<plugin>_result`` field of a response (a message ``FooResult`` with an enum ``result``)."""
    for f in desc.fields:
        mt = f.message_type
        if mt is not None and mt.name.endswith("Result") and "result" in mt.fields_by_name:
            rf = mt.fields_by_name["result"]
            if rf.enum_type is not None:
                return f
    return None


def data_fields(desc: Any) -> list[Any]:
    rf = result_field(desc)
    return [f for f in desc.fields if f is not rf]


def _set_result(native: Native, resp: Any, rf: Any, result: Any) -> None:
    sub = getattr(resp, rf.name)
    enum_desc = rf.message_type.fields_by_name["result"].enum_type
    sub.result = enum_to_pb(enum_desc, result)
    if "result_str" in rf.message_type.fields_by_name:
        name = result.name if isinstance(result, enum.Enum) else str(result)
        sub.result_str = name.replace("_", " ").capitalize()


def _native_result_enum(native: Native, rf: Any) -> Any:
    return native_type(native, rf.message_type.fields_by_name["result"].enum_type.full_name)


def fill_response(native: Native, resp: Any, value: Any) -> Any:
    """``resp`` from a native answer: a value, a (result, value) pair, a result, or None."""
    desc = resp.DESCRIPTOR
    rf = result_field(desc)
    fields = data_fields(desc)
    result_cls = _native_result_enum(native, rf) if rf is not None else None
    items = list(value) if isinstance(value, tuple) else [value]
    result = None
    if result_cls is not None:
        rest = []
        for item in items:
            if result is None and isinstance(item, result_cls):
                result = item
            else:
                rest.append(item)
        items = rest
        _set_result(native, resp, rf, result if result is not None else result_cls["SUCCESS"])
    items = [i for i in items if i is not None]
    if len(fields) == 1 and len(items) == 1:
        set_field(resp, fields[0], items[0])
    elif len(items) == len(fields):
        for f, item in zip(fields, items, strict=True):
            set_field(resp, f, item)
    elif items:
        raise TypeError(
            f"{desc.full_name}: cannot place the native answer {value!r} in fields {[f.name for f in fields]}"
        )
    return resp


def error_response(native: Native, resp: Any, exc: BaseException) -> bool:
    """Fill ``resp`` with the result of the native plugin error ``exc``; False if it is not one."""
    rf = result_field(resp.DESCRIPTOR)
    result = getattr(exc, "result", None)
    if rf is None or not isinstance(result, enum.Enum):
        return False
    try:
        _set_result(native, resp, rf, result)
    except ValueError:
        return False
    return True


# -- the channel ------------------------------------------------------------------------------------------


@dataclass
class Target:
    """What one RPC calls: the native function, and how to build its arguments."""

    plugin: str
    rpc: str
    call: Callable[..., Any] | None
    why_not: str = ""


class Backend:
    """One native ``Mavsdk`` with its first system: what a mavsdk_server process was for one ``System()``."""

    def __init__(self, native: Native, mavsdk_async: Any, system_async: Any) -> None:
        self.native = native
        self.mavsdk = mavsdk_async
        self.system = system_async
        self._plugins: dict[str, Any] = {}
        self._server_component: Any = None

    def plugin(self, name: str) -> Any:
        inst = self._plugins.get(name)
        if inst is None:
            cls = plugin_class(self.native, name)
            if cls is None:
                raise NotAvailableNatively(f"MAVSDK plugin {name!r} is not in the native core")
            params = list(inspect.signature(cls).parameters)
            if params and params[0] == "server_component":
                if self._server_component is None:
                    self._server_component = self.mavsdk._mavsdk.server_component(0)
                inst = cls(self._server_component)
            else:
                inst = cls(self.system)
            self._plugins[name] = inst
        return inst

    def destroy(self) -> None:
        """Release the native core: its system (with its plugins) and server component first, then the Mavsdk
        instance, which aborts the process if anything it handed out is still alive."""
        _alive.discard(self)
        try:
            if self.system is not None:
                self.system._system.destroy()
            if self._server_component is not None:
                self._server_component.destroy()
            self._plugins.clear()
            if self.mavsdk is not None:
                self.mavsdk.destroy()
        except Exception:  # pragma: no cover - best effort at exit
            log.debug("destroying the native Mavsdk failed", exc_info=True)


_alive: set[Backend] = set()
"""Every backend until ``destroy()``: the gRPC API's plugins, their channel and the backend reference each other,
and when the garbage collector frees such a cycle it clears weak references before finalizers run, so the native
``Mavsdk.__del__`` would find no systems to release first and ``mavsdk_destroy`` aborts the process ("A System
… must not outlive the Mavsdk instance"; seen with MAVSDK's logfile_download.py at its end)."""


def not_available(plugin: str, rpc: str) -> str:
    """Why ``plugin.rpc`` has no native counterpart ("" if it may have one)."""
    return NOT_AVAILABLE.get(f"{plugin}.{rpc}") or NOT_AVAILABLE.get(f"{plugin}.*") or ""


def native_method_name(cls: type, rpc: str, streaming: bool) -> str | None:
    """The native asyncio method for an RPC (``Arm`` → ``arm``; ``SubscribePosition`` → ``subscribe_position``,
    ``SubscribeUploadMissionWithProgress`` → ``upload_mission_with_progress``)."""
    name = _snake(rpc)
    if not streaming:
        return name if callable(getattr(cls, name, None)) else None
    candidates = [name]
    if name.startswith("subscribe_"):
        candidates.append(name.removeprefix("subscribe_"))
    for c in candidates:
        fn = getattr(cls, c, None)
        if fn is not None and inspect.isasyncgenfunction(fn):
            return c
    return None


async def _connection_state(backend: Backend) -> AsyncIterator[Any]:
    """core.connection_state(): the current state first (as mavsdk_server sends it), then every change."""
    raw = backend.system._system
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[bool] = asyncio.Queue()

    def on_change(connected: bool, _user_data: Any) -> None:
        loop.call_soon_threadsafe(queue.put_nowait, connected)

    handle = raw.subscribe_is_connected(on_change)
    try:
        yield SimpleNamespace(connection_state=SimpleNamespace(is_connected=bool(raw.is_connected())))
        while True:
            connected = await queue.get()
            yield SimpleNamespace(connection_state=SimpleNamespace(is_connected=connected))
    finally:
        raw.unsubscribe_is_connected(handle)


_SPECIAL: dict[str, Callable[[Backend], Any]] = {"core.SubscribeConnectionState": _connection_state}
"""RPCs answered here, not by a native plugin; they yield whole responses (as namespaces)."""


async def _play_tune(backend: Backend, tune_description: Any) -> Any:
    """tune.play_tune(): the native ``mavsdk`` 4.1.0 binding declares the C struct of a tune as one ``int`` for
    its song elements (``TuneDescription.to_c_struct`` fails on the list); the C function takes
    ``{const int *song_elements; size_t song_elements_size; int32_t tempo}`` (as ``libcmavsdk.so`` reads it).
    Called here with that struct, through a function pointer of our own (the binding's stays as it is)."""
    import ctypes

    tune = backend.native.types["tune"]
    plugin = backend.plugin("tune")._plugin

    class TuneDescriptionC(ctypes.Structure):
        _fields_ = [
            ("song_elements", ctypes.POINTER(ctypes.c_int)),
            ("song_elements_size", ctypes.c_size_t),
            ("tempo", ctypes.c_int32),
        ]

    elements = [int(e) for e in tune_description.song_elements]
    array = (ctypes.c_int * max(1, len(elements)))(*elements)
    c_tune = TuneDescriptionC(array, len(elements), int(tune_description.tempo))
    fn = plugin._lib["mavsdk_tune_play_tune"]  # a new function pointer: the binding's keeps its argtypes
    fn.argtypes = [ctypes.c_void_p, TuneDescriptionC]
    fn.restype = ctypes.c_int

    def call() -> Any:
        return tune.TuneResult(fn(plugin._require_handle(), c_tune))

    result = await asyncio.get_running_loop().run_in_executor(None, call)
    if result != tune.TuneResult.SUCCESS:
        raise tune.TuneError(result, "play_tune()", tune_description)
    return None


_FIXED: dict[str, Callable[..., Any]] = {"tune.PlayTune": _play_tune}
"""Unary RPCs whose native binding is broken, called here instead (``fn(backend, *native_args)``)."""


def _method(path: str) -> tuple[str, str, Any]:
    """``/mavsdk.rpc.action.ActionService/Arm`` → (``action``, ``Arm``, its MethodDescriptor)."""
    from google.protobuf import descriptor_pool

    service, rpc = path.strip("/").split("/")
    desc = descriptor_pool.Default().FindServiceByName(service).methods_by_name[rpc]
    plugin, _ = _plugin_of(service)
    return plugin, rpc, desc


def _request_args(backend: Backend, request: Any) -> list[Any]:
    return [_field_to_native(backend.native, f, getattr(request, f.name)) for f in request.DESCRIPTOR.fields]


def resolve(backend: Backend, plugin: str, rpc: str, streaming: bool) -> Callable[..., Any]:
    why = not_available(plugin, rpc)
    if why:
        raise NotAvailableNatively(
            f"{plugin}.{_snake(rpc)}() is not available on the native MAVSDK core ({why}); "
            "run with HARNESS_MAVSDK_GRPC=server to use mavsdk_server"
        )
    inst = backend.plugin(plugin)
    name = native_method_name(type(inst), rpc, streaming)
    if name is None:
        raise NotAvailableNatively(
            f"{plugin}.{_snake(rpc)}() has no counterpart in the native MAVSDK core "
            f"({type(inst).__name__}); run with HARNESS_MAVSDK_GRPC=server to use mavsdk_server"
        )
    fn: Callable[..., Any] = getattr(inst, name)
    return fn


class _Unary:
    def __init__(self, channel: NativeChannel, path: str, response_cls: type) -> None:
        self._channel, self._path, self._response_cls = channel, path, response_cls

    def __call__(self, request: Any, **_kw: Any) -> Any:
        return self._call(request)

    async def _call(self, request: Any) -> Any:
        backend = self._channel.backend
        plugin, rpc, _ = _method(self._path)
        fixed = _FIXED.get(f"{plugin}.{rpc}")
        fn = functools.partial(fixed, backend) if fixed else resolve(backend, plugin, rpc, streaming=False)
        resp = self._response_cls()
        try:
            value = await fn(*_request_args(backend, request))
        except Exception as e:
            if error_response(backend.native, resp, e):
                log.debug("%s.%s: %s", plugin, rpc, e)
                return resp
            raise
        return fill_response(backend.native, resp, value)


class _StreamCall:
    """One server-streaming call: an async iterator of responses with gRPC's ``cancel()``."""

    def __init__(self, channel: NativeChannel, path: str, response_cls: type, request: Any) -> None:
        self._channel, self._path, self._response_cls, self._request = channel, path, response_cls, request
        self._gen: Any = None
        self._cancelled = False

    def __aiter__(self) -> _StreamCall:
        return self

    async def __anext__(self) -> Any:
        if self._cancelled:
            raise StopAsyncIteration
        if self._gen is None:
            self._gen = self._responses()
        return await self._gen.__anext__()

    async def _responses(self) -> AsyncIterator[Any]:
        backend = self._channel.backend
        plugin, rpc, _ = _method(self._path)
        special = _SPECIAL.get(f"{plugin}.{rpc}")
        if special is not None:
            gen = special(backend)
            try:
                async for ns in gen:
                    resp = self._response_cls()
                    native_to_message(ns, resp)
                    yield resp
            finally:
                await gen.aclose()
            return
        fn = resolve(backend, plugin, rpc, streaming=True)
        gen = fn(*_request_args(backend, self._request))
        try:
            while True:
                try:
                    item = await gen.__anext__()
                except StopAsyncIteration:
                    return
                except Exception as e:
                    resp = self._response_cls()
                    if error_response(backend.native, resp, e):
                        yield resp  # the gRPC API raises its own error for it
                        return
                    raise
                yield fill_response(backend.native, self._response_cls(), item)
        finally:
            await gen.aclose()

    def cancel(self) -> bool:
        """Stop the stream (the native subscription ends), as gRPC's ``Call.cancel()``."""
        self._cancelled = True
        gen, self._gen = self._gen, None
        if gen is None:
            return True
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            return True

        async def close() -> None:
            try:
                await gen.aclose()
            except RuntimeError:  # still running in another task: that task's cancellation closes it
                pass

        task = loop.create_task(close())
        _closing.add(task)  # the loop keeps only a weak reference
        task.add_done_callback(_closing.discard)
        return True


_closing: set[asyncio.Task[None]] = set()


class _Stream:
    def __init__(self, channel: NativeChannel, path: str, response_cls: type) -> None:
        self._channel, self._path, self._response_cls = channel, path, response_cls

    def __call__(self, request: Any, **_kw: Any) -> _StreamCall:
        return _StreamCall(self._channel, self._path, self._response_cls, request)


def _response_class(deserializer: Any, path: str) -> type:
    cls = getattr(deserializer, "__self__", None)
    if isinstance(cls, type):
        return cls
    from google.protobuf import message_factory

    _, _, desc = _method(path)
    cls_: type = message_factory.GetMessageClass(desc.output_type)
    return cls_


class NativeChannel:
    """Stands in for the ``grpc.aio`` channel the gRPC API builds its stubs on."""

    def __init__(self, backend: Backend) -> None:
        self.backend = backend

    def unary_unary(
        self, path: str, request_serializer: Any = None, response_deserializer: Any = None, **_kw: Any
    ) -> _Unary:
        return _Unary(self, path, _response_class(response_deserializer, path))

    def unary_stream(
        self, path: str, request_serializer: Any = None, response_deserializer: Any = None, **_kw: Any
    ) -> _Stream:
        return _Stream(self, path, _response_class(response_deserializer, path))

    def stream_unary(self, path: str, *_a: Any, **_kw: Any) -> Any:  # not used by MAVSDK's protos
        raise NotAvailableNatively(f"{path}: client-streaming RPCs are not supported")

    stream_stream = stream_unary


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


# -- System ------------------------------------------------------------------------------------------------


PHASE_S = 0.02
"""A phase-0 period at the shipped rates: what was asked in one phase has been answered and read by the next."""


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
        old = getattr(self, "_harness_backend", None)
        if old is not None:
            old.destroy()
            self._harness_backend = None
        url = rewrite_url(system_address or DEFAULT_URL)
        log.info("mavsdk (gRPC API on the native core): connecting to %s", url)
        backend = await start_backend(native, url, self._sysid, self._compid)
        self._harness_backend = backend
        await _version_known(backend)
        manager = _PluginManager(NativeChannel(backend))
        self._plugins = {name: cls(manager) for name, cls in plugins.items()}

    def _stop_mavsdk_server(self: Any) -> None:
        backend = getattr(self, "_harness_backend", None)
        if backend is not None:
            self._harness_backend = None
            backend.destroy()

    System.__init__ = __init__
    System.connect = connect
    System._stop_mavsdk_server = _stop_mavsdk_server
    System._harness_native = True
