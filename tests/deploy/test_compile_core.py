"""tools/compile-core: the request path compiled with mypyc runs the same as its sources.

In a copy of the checkout (this clone stays as it is), the script compiles; the compiled modules are the ones
Python imports; every reply to a set of requests is byte for byte the sources' reply; the unit tests pass on
the compiled modules; an edit after compiling is said at import; ``--remove`` goes back to the sources.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: what of the checkout the copy leaves out: git, environments, caches and builds
LEFT_OUT = (".git", ".venv*", "__pycache__", "*.so", "build", "dist", ".hypothesis", ".*_cache", "*.egg-info")

#: replies of one drive to a read, writes (a new set speed, the same again, a refused one), a bad CRC, an
#: unknown function and a broadcast, as hex lines: what a compiled path must answer byte for byte
REPLIES = """
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.wire.framing import RtuFramer
from c20sim.wire.protocol import with_crc
sim = Simulator(load_profile(), (1, 2), clock=VirtualClock(), seed=3)
for body in ["01 03 20 01 00 01", "01 06 20 01 05 DC", "01 06 20 01 05 DC", "01 06 20 00 00 01", "01 03 30 00 00 08",
             "02 06 F0 00 00 05", "01 04 20 00 00 01", "00 06 20 01 01 F4", "02 03 20 01 00 01", "01 10 20 00 00 02 04 00 07 00 00"]:
    sim.advance(0.25)
    framer = RtuFramer(19200, complete_on_length=True, check_gaps=False)
    framer.feed(with_crc(bytes.fromhex(body)), sim.now())
    framer.flush()
    for event in framer.events():
        reply = sim.handle(event)
        print(body, "->", "silence" if reply is None else reply.data.hex(" "))
framer = RtuFramer(19200, complete_on_length=True, check_gaps=False)
framer.feed(bytes.fromhex("01 03 20 01 00 01 00 00"), sim.now())
framer.flush()
print("bad crc ->", [(e.kind.value, sim.handle(e)) for e in framer.events()][0][0])
print(sim.drive(1).telemetry())
"""


def run(argv: list[str], cwd: Path, *, pythonpath: Path | None, timeout: float) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env, check=False)


@pytest.fixture(scope="module")
def compiled(tmp_path_factory: pytest.TempPathFactory) -> Path:
    copy = tmp_path_factory.mktemp("compile-core") / "checkout"
    shutil.copytree(ROOT, copy, ignore=shutil.ignore_patterns(*LEFT_OUT))
    built = run([str(copy / "tools" / "compile-core"), sys.executable], copy, pythonpath=None, timeout=900)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    listed = (ROOT / "tools" / "compile-core").read_text().split("MODULES=(", 1)[1].split(")", 1)[0].split()
    assert f"{len(listed)} modules compiled" in built.stdout
    return copy


def test_the_compiled_modules_are_the_ones_imported(compiled: Path) -> None:
    code = "import c20sim.wire.protocol as p, c20sim.core.bus as b, c20sim.transport.tcp as t; print(p.__file__, b.__file__, t.__file__)"
    result = run([sys.executable, "-c", code], compiled, pythonpath=compiled, timeout=60)
    assert result.returncode == 0 and result.stderr == "", result.stderr
    paths = result.stdout.split()
    assert len(paths) == 3 and all(p.startswith(str(compiled)) and p.endswith(".so") for p in paths), paths


def test_every_reply_is_the_sources_byte_for_byte(compiled: Path) -> None:
    plain = run([sys.executable, "-c", REPLIES], ROOT, pythonpath=ROOT, timeout=60)
    fast = run([sys.executable, "-c", REPLIES], compiled, pythonpath=compiled, timeout=60)
    assert plain.returncode == 0, plain.stderr
    assert fast.returncode == 0, fast.stderr
    assert fast.stdout == plain.stdout
    assert "01 03 20 01 00 01 -> 01 03 02 00 00" in plain.stdout  # the replies were really made
    assert "-> silence" in plain.stdout and "bad crc -> crc error" in plain.stdout


def test_the_unit_tests_pass_on_the_compiled_modules(compiled: Path) -> None:
    result = run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-x", "-m", "not sources_only", "tests/unit"],
        compiled,
        pythonpath=compiled,
        timeout=600,
    )
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert " passed" in result.stdout and "failed" not in result.stdout


def test_an_edit_after_compiling_is_said_and_remove_goes_back_to_the_sources(compiled: Path) -> None:
    source = compiled / "c20sim" / "wire" / "registers.py"
    [built] = source.parent.glob("registers.cpython-*.so")
    later = built.stat().st_mtime + 60  # an edit a minute after the build
    os.utime(source, (later, later))
    said = run([sys.executable, "-c", "import c20sim"], compiled, pythonpath=compiled, timeout=60)
    assert said.returncode == 0
    assert said.stderr == (
        "c20sim: warning: c20sim/wire/registers.py changed after tools/compile-core compiled them, and the"
        " compiled code runs: run tools/compile-core again, or tools/compile-core --remove\n"
    )
    removed = run([str(compiled / "tools" / "compile-core"), "--remove"], compiled, pythonpath=None, timeout=60)
    assert removed.returncode == 0, removed.stderr
    assert not list((compiled / "c20sim").rglob("*.so")) and not list(compiled.glob("*__mypyc*.so"))
    plain = run(
        [sys.executable, "-c", "import c20sim.wire.protocol as p; print(p.__file__)"],
        compiled,
        pythonpath=compiled,
        timeout=60,
    )
    assert (plain.stdout.strip(), plain.stderr) == (str(compiled / "c20sim" / "wire" / "protocol.py"), "")
