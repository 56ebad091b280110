"""deploy/build-image's own errors: one line on stderr and exit 2, before anything is built."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

BUILD_IMAGE = Path(__file__).resolve().parents[2] / "deploy" / "build-image"


def build_image(*args: str, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["bash", str(BUILD_IMAGE), *args],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, **env},
        check=False,
    )


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--tag"], "deploy/build-image: --tag needs an image name, such as localhost/c20sim:dev\n"),
        (["--base"], "deploy/build-image: --base needs an image name\n"),
        (["--mirror"], "deploy/build-image: --mirror needs a URL\n"),
        (["--bogus"], "deploy/build-image: unknown option --bogus; see --help\n"),
    ],
)
def test_bad_options_are_one_line_and_exit_2(args: list[str], message: str) -> None:
    result = build_image(*args)
    assert (result.returncode, result.stdout, result.stderr) == (2, "", message)


def test_a_python_older_than_3_11_is_refused_with_the_reason(tmp_path: Path) -> None:
    fake = tmp_path / "python3.10"
    fake.write_text("#!/bin/sh\nexit 1\n")  # answers the version check as a 3.10 would
    fake.chmod(0o755)
    result = build_image(PYTHON=str(fake), PATH=f"{tmp_path}:{os.environ['PATH']}")
    if result.stderr.startswith("deploy/build-image: podman is not installed") or "mmdebstrap is not" in result.stderr:
        pytest.skip("podman or mmdebstrap absent: the tool check comes first")
    assert result.returncode == 2
    assert result.stderr == (
        f"deploy/build-image: {fake} is not Python 3.11 or newer: it builds the project's wheel and fetches the "
        "image's (set PYTHON)\n"
    )


def test_help_is_the_header() -> None:
    result = build_image("--help")
    assert result.returncode == 0
    assert result.stdout.startswith("Build the OCI image localhost/c20sim:<version> from Debian's packages")
    assert "--reuse-base" in result.stdout and "set -euo" not in result.stdout
