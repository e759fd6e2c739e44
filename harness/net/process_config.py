"""The configuration of the network process (``python -m harness.net.subscriber``) as one typed value.

``harness run`` writes it as ``<run dir>/network.json`` and the process reads it with ``--config FILE``: the
model's parameters arrive as the scenario gave them (no JSON string in argv parsed back) and the run directory
as a field (not ``$HARNESS_RUN_DIR`` read back). The flags remain for a process started by hand and build the
same value. A light module: the launcher imports it without a network model.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgspec

from harness.core.files import read_child_config
from harness.net.model import NetworkKind


class NetworkProcessConfig(msgspec.Struct, frozen=True, kw_only=True):
    """One network process: what ``harness run`` writes as ``<run dir>/network.json``. Secrets never go here
    (the channel secret comes in the environment)."""

    address: str
    """The channel to join."""
    model: NetworkKind = NetworkKind.BUILTIN
    seed: int = 0
    params: dict[str, Any] = msgspec.field(default_factory=dict)
    """The model's parameters (the scenario's ``network.params``)."""
    name: str = "network"
    """This process's name in the channel."""
    run_dir: str | None = None
    """Append every delivery and drop to ``network-events.jsonl`` here (None: nowhere)."""

    def to_json(self) -> bytes:
        return msgspec.json.encode(self)

    @classmethod
    def read(cls, path: Path) -> NetworkProcessConfig:
        """The configuration in ``path``; :class:`ScenarioError` when it cannot be read or is not one."""
        return read_child_config(path, cls, "a network process configuration")
