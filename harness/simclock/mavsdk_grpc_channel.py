"""The calls of MAVSDK's gRPC API on the native MAVSDK core: the channel its plugin stubs are built on.

The gRPC API's plugin classes (``mavsdk_grpc.action.Action`` …) talk to a stub built on a gRPC channel
(``AsyncBase._setup_stub(channel)``); :class:`NativeChannel` stands in for it, and each RPC
(``/mavsdk.rpc.action.ActionService/Arm``) becomes a call of the native asyncio plugin
(``mavsdk.asyncio.plugins.action.ActionAsync.arm``) of a :class:`Backend` (what a mavsdk_server process was for
one ``System()``). Which native method, derived, not written per method:

- the plugin is the proto package (``mavsdk.rpc.<plugin>``), its native class the ``*Async`` class of
  ``mavsdk.asyncio.plugins.<plugin>``, built on the system (or on the server component, for ``*_server``
  plugins, whose native constructor takes ``server_component``);
- a unary RPC ``FooBar`` is the native ``foo_bar``; a server-streaming RPC ``SubscribeFooBar`` is the native
  async generator ``subscribe_foo_bar`` (or ``foo_bar``, for the progress streams: ``upload_mission_with_progress``,
  ``calibrate_gyro``, ftp ``download``);
- the request's fields, in order, are its arguments, and its answer fills the response
  (:mod:`.mavsdk_grpc_mapping`).

Written here by hand (:data:`HAND_WRITTEN`, called as the native method would be): ``core``, which has no native
plugin (its connection-state stream is the native system's ``is_connected``, the current state first, as
mavsdk_server sends it), and ``tune.play_tune``, whose native binding is broken. What the native core lacks
(:data:`NOT_AVAILABLE`) raises :class:`~.mavsdk_grpc_mapping.NotAvailableNatively` when called, naming the method.
"""

from __future__ import annotations

import asyncio
import functools
import inspect
import logging
from collections.abc import AsyncIterator, Callable
from types import SimpleNamespace
from typing import Any

from harness.simclock.mavsdk_grpc_mapping import (
    Native,
    NotAvailableNatively,
    error_response,
    field_to_native,
    fill_response,
    plugin_class,
    snake,
    split_proto_name,
)

log = logging.getLogger(__name__)

NOT_AVAILABLE: dict[str, str] = {
    "core.SetMavlinkTimeout": "the native core has no MAVLink time-out setting",
    "core.FeedHeartbeatWatchdog": "the native core has no heartbeat watchdog",
    "core.SetHeartbeatWatchdogTimeout": "the native core has no heartbeat watchdog",
    "component_metadata_server.*": "the native mavsdk 4.1.0 package fails to import this plugin",
    "tracking_server.*": "the native core has no tracking_server plugin",
}
"""gRPC methods (``plugin.Rpc``, or ``plugin.*`` for a whole plugin) without a native counterpart, and why."""


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


def not_available(plugin: str, rpc: str) -> str:
    """Why ``plugin.rpc`` has no native counterpart ("" if it may have one)."""
    return NOT_AVAILABLE.get(f"{plugin}.{rpc}") or NOT_AVAILABLE.get(f"{plugin}.*") or ""


def native_method_name(cls: type, rpc: str, streaming: bool) -> str | None:
    """The native asyncio method for an RPC (``Arm`` → ``arm``; ``SubscribePosition`` → ``subscribe_position``,
    ``SubscribeUploadMissionWithProgress`` → ``upload_mission_with_progress``)."""
    name = snake(rpc)
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
    """core.connection_state(): the current state first (as mavsdk_server sends it), then every change (as the
    native ``ConnectionState`` would be, had the native core a ``core`` plugin)."""
    raw = backend.system._system
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[bool] = asyncio.Queue()

    def on_change(connected: bool, _user_data: Any) -> None:
        loop.call_soon_threadsafe(queue.put_nowait, connected)

    handle = raw.subscribe_is_connected(on_change)
    try:
        yield SimpleNamespace(is_connected=bool(raw.is_connected()))
        while True:
            yield SimpleNamespace(is_connected=await queue.get())
    finally:
        raw.unsubscribe_is_connected(handle)


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


HAND_WRITTEN: dict[str, Callable[..., Any]] = {
    "core.SubscribeConnectionState": _connection_state,
    "tune.PlayTune": _play_tune,
}
"""RPCs answered here as a native method would (``fn(backend, *native_args)``): ``core``, which has no native
plugin, and those whose native binding is broken."""


def _method(path: str) -> tuple[str, str, Any]:
    """``/mavsdk.rpc.action.ActionService/Arm`` → (``action``, ``Arm``, its MethodDescriptor)."""
    from google.protobuf import descriptor_pool

    service, rpc = path.strip("/").split("/")
    desc = descriptor_pool.Default().FindServiceByName(service).methods_by_name[rpc]
    plugin, _ = split_proto_name(service)
    return plugin, rpc, desc


def resolve(backend: Backend, plugin: str, rpc: str, streaming: bool) -> Callable[..., Any]:
    """What answers ``plugin.Rpc``: a hand-written RPC, or the native method (its coroutine function, or its async
    generator function for a stream)."""
    own = HAND_WRITTEN.get(f"{plugin}.{rpc}")
    if own is not None:
        return functools.partial(own, backend)
    server = "run with HARNESS_MAVSDK_GRPC=server to use mavsdk_server"
    why = not_available(plugin, rpc)
    if why:
        raise NotAvailableNatively(
            f"{plugin}.{snake(rpc)}() is not available on the native MAVSDK core ({why}); {server}"
        )
    inst = backend.plugin(plugin)
    name = native_method_name(type(inst), rpc, streaming)
    if name is None:
        raise NotAvailableNatively(
            f"{plugin}.{snake(rpc)}() has no counterpart in the native MAVSDK core ({type(inst).__name__}); {server}"
        )
    fn: Callable[..., Any] = getattr(inst, name)
    return fn


def _start(backend: Backend, path: str, request: Any, streaming: bool) -> tuple[str, Any]:
    """Start the native call of the RPC at ``path`` with the request's fields as its arguments:
    (``plugin.Rpc``, its coroutine, or its async generator for a stream)."""
    plugin, rpc, _ = _method(path)
    fn = resolve(backend, plugin, rpc, streaming)
    args = [field_to_native(backend.native, f, getattr(request, f.name)) for f in request.DESCRIPTOR.fields]
    return f"{plugin}.{rpc}", fn(*args)


class _Rpc:
    """One RPC of a stub (``stub.Arm``): its path and response class, on the channel."""

    def __init__(self, channel: NativeChannel, path: str, response_cls: type) -> None:
        self._channel, self._path, self._response_cls = channel, path, response_cls


class _Unary(_Rpc):
    def __call__(self, request: Any, **_kw: Any) -> Any:
        return self._call(request)

    async def _call(self, request: Any) -> Any:
        backend = self._channel.backend
        resp = self._response_cls()
        name, call = _start(backend, self._path, request, streaming=False)
        try:
            value = await call
        except Exception as e:
            if error_response(backend.native, resp, e):
                log.debug("%s: %s", name, e)
                return resp
            raise
        return fill_response(backend.native, resp, value)


class _StreamCall:
    """One server-streaming call: an async iterator of responses with gRPC's ``cancel()``."""

    def __init__(self, stream: _Stream, request: Any) -> None:
        self._stream, self._request = stream, request
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
        stream = self._stream
        backend = stream._channel.backend
        _, gen = _start(backend, stream._path, self._request, streaming=True)
        try:
            while True:
                try:
                    item = await gen.__anext__()
                except StopAsyncIteration:
                    return
                except Exception as e:
                    resp = stream._response_cls()
                    if error_response(backend.native, resp, e):
                        yield resp  # the gRPC API raises its own error for it
                        return
                    raise
                yield fill_response(backend.native, stream._response_cls(), item)
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


class _Stream(_Rpc):
    def __call__(self, request: Any, **_kw: Any) -> _StreamCall:
        return _StreamCall(self, request)


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
