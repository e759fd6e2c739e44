"""Limits on what comes from outside: how much of a value an error message echoes, how big and how deeply
nested a file the harness reads may be.

    cut("x" * 10_000)          # 'xxxx…' (ECHO_CHARS characters at most)
    shown(value)               # repr(value), cut: what an error says it got
    depth(data, 32) > 32       # nested deeper than 32 levels (it stops counting there)
"""

from __future__ import annotations

from typing import Any

ECHO_CHARS = 60
"""At most this many characters of a value a user gave appear in an error message."""
ERROR_CHARS = 1000
"""At most this many characters of an error message are printed (the last guard: values are cut before)."""


def cut(text: str, limit: int = ECHO_CHARS) -> str:
    """``text``, or its first ``limit - 1`` characters and "…" when it is longer: the one place an echoed value
    is shortened (a 10 MB key in a scenario file is one short line, not 10 MB of terminal)."""
    return text if len(text) <= limit else text[: max(0, limit - 1)] + "…"


def shown(value: Any, limit: int = ECHO_CHARS) -> str:
    """``repr(value)`` cut to ``limit`` characters (``repr`` of a long string or a deep list only as far as needed)."""
    if isinstance(value, str) and len(value) > limit:
        value = value[: limit + 1]
    try:
        text = repr(value)
    except ValueError:  # an int of more digits than Python converts to text
        text = "an integer of more than 4300 digits"
    return cut(text, limit)


def depth(data: Any, limit: int) -> int:
    """How deeply ``data`` (dicts and lists) nests, counted up to ``limit + 1`` (then it stops looking)."""
    deepest = 0
    todo: list[tuple[Any, int]] = [(data, 0)]
    while todo:
        node, d = todo.pop()
        if isinstance(node, dict):
            children: Any = node.values()
        elif isinstance(node, list):
            children = node
        else:
            continue
        d += 1
        deepest = max(deepest, d)
        if deepest > limit:
            return deepest
        todo.extend((c, d) for c in children)
    return deepest
