"""Every bad input to a command: one line naming the file or option, the key and what is allowed; exit 2.

Non-finite numbers first: a ``nan`` in a profile or ``--speed nan`` used to
start a server that then answered no read at all (``cannot convert float NaN
to integer``). Then inputs that used to end in a traceback and exit 1.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from c20sim.drive.profile import profile_path
from tests.integration.conftest import c20sim_run, one_line


@pytest.fixture
def files(tmp_path: Path) -> Path:
    shipped = profile_path("c20-400hr").read_text()
    assert "\ninertia_kg_m2 = " in shipped
    patched = ["inertia_kg_m2 = nan" if line.startswith("inertia_kg_m2 = ") else line for line in shipped.splitlines()]
    (tmp_path / "nan.toml").write_text("\n".join(patched) + "\n")
    (tmp_path / "latin1.toml").write_bytes(b'name = "caf\xe9"\n')
    (tmp_path / "deep.json").write_text("[" * 100_000)
    return tmp_path


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (
            ["serve", "--tcp", "127.0.0.1:0", "--profile", "nan.toml"],
            "c20sim: nan.toml: motor.inertia_kg_m2: must be a finite number, not nan; allowed 1e-07 to 10 kg m^2",
        ),
        (["serve", "--tcp", "127.0.0.1:0", "--speed", "nan"], "c20sim: --speed nan: give a clock speed factor from "),
        (["serve", "--tcp", "127.0.0.1:0", "--speed", "inf"], "c20sim: --speed inf: give a clock speed factor from "),
        (["serve", "--tcp", "127.0.0.1:0", "--speed", "1e308"], "c20sim: --speed 1e+308: give a clock speed factor"),
        (
            ["serve", "--tcp", "127.0.0.1:0", "--log-frames-max-mb", "nan"],
            "c20sim: --log-frames-max-mb nan: give a size in MiB from 0.01 to 1000000",
        ),
        (
            ["serve", "--tcp", "127.0.0.1:0", "--profile", "latin1.toml"],
            "c20sim: latin1.toml: not a TOML profile: not UTF-8 text (byte 11)",
        ),
        (
            ["serve", "--tcp", "127.0.0.1:0", "--state", "deep.json"],
            "c20sim: deep.json: not a c20sim state file (JSON nested too deeply)",
        ),
        (
            ["serve", "--tcp", "[::1]"],
            "c20sim: --tcp '[::1]': no port after [::1]; give HOST:PORT, such as 127.0.0.1:5020 or [::1]:5020",
        ),
        (["serve", "--tcp", "::1:5020"], "c20sim: --tcp '::1:5020': put an IPv6 address in brackets: [::1]:5020"),
        (["serve", "--tcp", "[fe80::1%lo]:0"], "c20sim: --tcp [fe80::1%lo]:0: cannot listen: "),
        (
            ["ctl", "--url", "not a url", "time"],
            "c20sim: --url 'not a url': give the API's address as http://HOST:PORT, such as http://127.0.0.1:8020",
        ),
    ],
)
def test_bad_input_is_one_line_and_exit_2(files: Path, args: list[str], expected: str) -> None:
    assert one_line(c20sim_run(*args, cwd=files)).startswith(expected)
