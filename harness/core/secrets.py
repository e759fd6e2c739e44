"""Secrets come from files or the environment, never from a command line (``ps`` shows every process's argv).

- The MAVLink signing key: a file holding the 32-byte key as 64 hexadecimal characters (``--signing-key-file``,
  ``[mavlink] signing_key_file``); child processes get the file's path, not the key.
- The channel secret (a tree of channels across machines): ``--secret-file PATH``, or the environment
  (``HARNESS_SECRET``, or the older ``HARNESS_CHANNEL_SECRET``), which children inherit and which only the
  same user (and root) can read in ``/proc/<pid>/environ``.
"""

from __future__ import annotations

import os
import string
from pathlib import Path

from harness.core.errors import ScenarioError
from harness.core.files import read_text

SECRET_ENV = ("HARNESS_SECRET", "HARNESS_CHANNEL_SECRET")
_HEX = frozenset(string.hexdigits)


def read_signing_key(path: Path, field: str) -> bytes:
    """The 32-byte key in ``path`` (64 hex characters, surrounding whitespace ignored); one error line naming
    ``field`` when the file is missing, unreadable, too short or long, or not hexadecimal."""
    try:
        text = path.read_text(encoding="ascii", errors="replace").strip()
    except FileNotFoundError:
        raise ScenarioError(f"{field}: {path} does not exist") from None
    except OSError as exc:
        raise ScenarioError(f"{field}: {path} cannot be read ({exc.strerror})") from None
    if len(text) != 64:
        raise ScenarioError(
            f"{field}: {path} must hold the 32-byte key as 64 hexadecimal characters, it holds {len(text)} characters"
        )
    if not set(text) <= _HEX:
        bad = next(c for c in text if c not in _HEX)
        raise ScenarioError(f"{field}: {path} must hold 64 hexadecimal characters, found {bad!r}")
    return bytes.fromhex(text)


def channel_secret(given: str | None, secret_file: str | None) -> bytes | None:
    """The channel secret: ``--secret-file``, else ``--secret`` (visible in ``ps``: kept for old scripts), else
    the environment; None when there is none."""
    if secret_file is not None:
        path = Path(secret_file)
        text = read_text(path, "--secret-file").strip()
        if not text:
            raise ScenarioError(f"--secret-file: {path} is empty")
        return text.encode()
    if given:
        return given.encode()
    for name in SECRET_ENV:
        value = os.environ.get(name)
        if value:
            return value.encode()
    return None
