"""The channel secret from a file or the environment, never in ``ps`` (issue 17, item 5)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from harness.core.errors import ScenarioError, SimulationError
from harness.wire import protocol as p
from harness.wire.client import ChannelClient

SECRET = "correct horse battery staple 4711"


def _channel(tmp_path: Path, *args: str, secret_env: str | None = None) -> tuple[subprocess.Popen[str], str]:
    env = {k: v for k, v in os.environ.items() if k not in ("HARNESS_SECRET", "HARNESS_CHANNEL_SECRET")}
    if secret_env is not None:
        env["HARNESS_SECRET"] = secret_env
    proc = subprocess.Popen(
        [sys.executable, "-m", "harness.cli", "channel", "--listen", "tcp://0.0.0.0:0", "--name", "root", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    found = re.search(r"listening on tcp://[^:]+:(\d+)", line)
    if found is None:
        proc.kill()
        raise AssertionError(f"no listening line: {line!r} {proc.communicate()}")
    return proc, f"tcp://127.0.0.1:{found.group(1)}"


def _stop(proc: subprocess.Popen[str]) -> str:
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=10)
    return err


@pytest.mark.parametrize("how", ["file", "environment"])
def test_channel_takes_its_secret_from_a_file_or_the_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, how: str
) -> None:
    secret_file = tmp_path / "secret"
    secret_file.write_text(SECRET + "\n")
    if how == "file":
        proc, address = _channel(tmp_path, "--secret-file", str(secret_file))
    else:
        proc, address = _channel(tmp_path, secret_env=SECRET)
    try:
        assert SECRET.encode() not in Path(f"/proc/{proc.pid}/cmdline").read_bytes()
        with pytest.raises(SimulationError, match="did not prove the shared secret"):
            ChannelClient.connect(address, p.PeerKind.TYPE0, "intruder", secret=b"wrong")
        monkeypatch.delenv("HARNESS_CHANNEL_SECRET", raising=False)
        monkeypatch.setenv("HARNESS_SECRET", SECRET)  # a child of a run inherits it: no argument needed
        ChannelClient.connect(address, p.PeerKind.TYPE0, "friend").close()
    finally:
        _stop(proc)


def test_channel_secret_on_the_command_line_warns_that_ps_shows_it(tmp_path: Path) -> None:
    proc, _ = _channel(tmp_path, "--secret", SECRET)
    err = _stop(proc)
    assert "--secret shows in ps; prefer --secret-file or $HARNESS_SECRET" in err


def test_unreadable_or_empty_secret_file_is_one_line(tmp_path: Path) -> None:
    from harness.core.secrets import channel_secret

    (tmp_path / "empty").write_text("\n")
    with pytest.raises(ScenarioError, match=r"^--secret-file: .*empty is empty$"):
        channel_secret(None, str(tmp_path / "empty"))
    with pytest.raises(ScenarioError, match=r"^--secret-file .*nope: the file does not exist$"):
        channel_secret(None, str(tmp_path / "nope"))
    (tmp_path / "latin1").write_bytes(b"s\xe9cret\n")
    with pytest.raises(ScenarioError, match=r"^--secret-file .*latin1: not UTF-8 text \(byte 0xe9 on line 1\)"):
        channel_secret(None, str(tmp_path / "latin1"))
    with pytest.raises(ScenarioError, match=r"^--secret-file .*: this is a directory"):
        channel_secret(None, str(tmp_path))
