"""The derived mapping between MAVSDK's gRPC API and the native MAVSDK core: types and values.

The native package (:func:`load_native`, kept apart from ``sys.modules``, where a gRPC script's ``mavsdk`` is
``mavsdk_grpc``), the native class of each plugin (:func:`plugin_class`), and the conversion of protobuf values
both ways, derived from the protos and the two packages rather than written per message:

- a protobuf message is the native class of the same proto name (``mavsdk.rpc.mission.MissionItem`` ↔
  ``mavsdk.plugins.mission.MissionItem``), field by field, recursively, lists too;
- an enum goes by value name (``FLIGHT_MODE_HOLD`` ↔ ``FlightMode.HOLD``); a proto ``FooResult.Result`` is the
  native ``FooResult``;
- a response gets the native answer in its one data field (or its fields, in order) and its ``<plugin>_result``,
  which is SUCCESS unless the native call raised the plugin's error (``ActionError(ActionResult.DENIED)``),
  whose result goes there instead (:func:`fill_response`, :func:`error_response`).

The calls that use it are :mod:`.mavsdk_grpc_channel`; the ``System`` they serve, :mod:`.mavsdk_grpc_native`.
"""

from __future__ import annotations

import enum
import importlib
import pkgutil
import re
import sys
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any


class NotAvailableNatively(RuntimeError):
    """A gRPC-API method the native MAVSDK core does not have (see ``HARNESS_MAVSDK_GRPC=server``)."""


def snake(name: str) -> str:
    """``SubscribeFlightMode`` → ``subscribe_flight_mode``."""
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower()


def _upper_snake(name: str) -> str:
    return snake(name).upper()


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


def split_proto_name(full_name: str) -> tuple[str, list[str]]:
    """``mavsdk.rpc.mission.MissionItem.CameraAction`` → (``mission``, [``MissionItem``, ``CameraAction``])."""
    parts = full_name.split(".")
    assert parts[:2] == ["mavsdk", "rpc"], full_name
    return parts[2], parts[3:]


def native_type(native: Native, full_name: str) -> Any:
    """The native class or enum of a proto message or enum (by its full proto name)."""
    plugin, path = split_proto_name(full_name)
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
        setattr(obj, f.name, field_to_native(native, f, getattr(msg, f.name)))
    return obj


def field_to_native(native: Native, f: Any, value: Any) -> Any:
    """The value of the protobuf field ``f`` (a list, for a repeated one) as the native API takes it."""
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
    """Set the field ``f`` of ``msg`` from a native value (a list, for a repeated field); None leaves it unset."""
    if value is None:
        return
    if _is_repeated(f):
        target = getattr(msg, f.name)
        for v in value:
            if f.message_type is not None:
                native_to_message(v, target.add())
            else:
                target.append(_scalar_to_pb(f, v))
    elif f.message_type is not None:
        native_to_message(value, getattr(msg, f.name))
    else:
        setattr(msg, f.name, _scalar_to_pb(f, value))


def _scalar_to_pb(f: Any, value: Any) -> Any:
    """One native value of the non-message field ``f`` as protobuf takes it (enums by value name)."""
    if f.enum_type is not None:
        return enum_to_pb(f.enum_type, value)
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


def _set_result(resp: Any, rf: Any, result: Any) -> None:
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
        _set_result(resp, rf, result if result is not None else result_cls["SUCCESS"])
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
        _set_result(resp, rf, result)
    except ValueError:
        return False
    return True
