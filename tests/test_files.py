"""Input files and the run directory as one line each (``harness.core.files``)."""

from __future__ import annotations

import errno
from pathlib import Path

import pytest

from harness.core.errors import ScenarioError
from harness.core.files import RecordingError, read_text, script_file, writable_dir


def test_input_files_fail_in_one_line_naming_them(tmp_path: Path) -> None:
    good = tmp_path / "good.toml"
    good.write_text("vehicles = 1  # ünïcode\n")
    assert read_text(good, "scenario file") == "vehicles = 1  # ünïcode\n"
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"a = 1\nb = 2\nc = '\xe9'\n")
    with pytest.raises(ScenarioError) as info:
        read_text(bad, "scenario file")
    assert str(info.value) == f"scenario file {bad}: not UTF-8 text (byte 0xe9 on line 3); save it as UTF-8"
    with pytest.raises(ScenarioError, match=r": the file does not exist$"):
        read_text(tmp_path / "nope", "x")
    with pytest.raises(ScenarioError, match=r": this is a directory; give the path of a file$"):
        read_text(tmp_path, "x")
    with pytest.raises(ScenarioError, match=r"^--mission .*: this is a directory; give the path of a script$"):
        script_file(tmp_path, "--mission")
    with pytest.raises(ScenarioError, match=r"^--mission .*nope: the file does not exist$"):
        script_file(tmp_path / "nope", "--mission")
    assert script_file(good, "--mission") == good


def test_the_run_directory_is_tried_before_anything_starts(tmp_path: Path) -> None:
    writable_dir(tmp_path / "a" / "b")
    assert (tmp_path / "a" / "b").is_dir() and not any((tmp_path / "a" / "b").iterdir()), "no probe left behind"
    (tmp_path / "f").write_text("")
    with pytest.raises(ScenarioError, match=r"f: this is a file, not a directory; give --out a directory$"):
        writable_dir(tmp_path / "f")
    with pytest.raises(ScenarioError, match=r"f/sub: cannot write there: Not a directory; a file stands where"):
        writable_dir(tmp_path / "f" / "sub")


def test_a_recording_error_names_the_file_and_what_to_do() -> None:
    err = RecordingError.of(Path("/r/world.mcap"), OSError(errno.ENOSPC, "No space left on device"))
    assert str(err) == (
        "could not write /r/world.mcap: No space left on device (the file system is full: free space there or give "
        "--out a directory on another one); the recording is incomplete"
    )
    assert err.path == Path("/r/world.mcap")
