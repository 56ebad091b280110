"""The bounded reader's nesting checks: brackets in strings and comments are not nesting; no recursion."""

from __future__ import annotations

from pathlib import Path

import pytest

from c20sim.drive.files import MAX_DEPTH, FileReadError, json_depth, read_bytes, toml_depth
from c20sim.drive.profile import profile_path


def test_toml_depth_skips_strings_and_comments() -> None:
    quoted = 'a = "' + "[" * 100 + "\"\nb = '" + "{" * 100 + "'\n# " + "[" * 100 + "\n"
    multi = 'c = """\n' + "[" * 100 + '\\"""\n"""\n'
    assert toml_depth(quoted + multi) <= 1
    assert toml_depth("x = " + "[" * 100 + "]" * 100) == 100
    assert toml_depth(".".join(["k"] * 100) + " = 1") == 99
    assert toml_depth("x = [" + ", ".join(["1.5"] * 100) + "]") == 1  # a number's dot is no nesting


def test_every_shipped_profile_is_within_the_depth() -> None:
    for name in ("c20-400hr", "c20-2200hv"):
        text = profile_path(name).read_text()
        assert toml_depth(text) <= 4, name


def test_json_depth() -> None:
    assert json_depth('{"a": "[[[[", "b": [[1]]}') <= MAX_DEPTH  # few brackets: counted, not scanned
    text = '{"a": "' + "[" * 100 + '", "b": [[1]]}'
    assert json_depth(text) == 3
    assert json_depth("[" * 10_000) == 10_000
    assert MAX_DEPTH == 64


def test_a_directory_is_refused(tmp_path: Path) -> None:
    with pytest.raises(FileReadError, match="is a directory, not a regular file; give the profile as a file"):
        read_bytes(tmp_path, "profile")
