"""The dialect learned from the device: drives served from profiles with known dialect changes, probed by
``c20sim exercise --dialect-only`` over the line-timed pty, RTU over TCP and Modbus TCP; ``c20sim fit`` learns
each quirk the probe can reach on that link exactly, and ``c20sim replay`` of the capture against the fitted
profile finds no reply that differs (against the shipped profile it does)."""

from __future__ import annotations

import subprocess
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest

from c20sim.drive.profile import load_profile
from c20sim.traffic.capture import load_frame_log
from tests.conftest import wait_for_ready_file
from tests.integration.conftest import c20sim_command, c20sim_run, one_line

#: Two drives whose dialects differ from the shipped profile's (true, 1, 6, true), each in a way the format holds.
DIALECTS = {
    "modbus-ish": {
        "reply_to_bad_crc": False,
        "max_read_registers": 8,
        "byte_count_exception": 3,
        "ram_only_alias": False,
    },
    "wide-reads": {
        "reply_to_bad_crc": True,
        "max_read_registers": 125,
        "byte_count_exception": 6,
        "ram_only_alias": True,
    },
}

LINKS = [("pty", ""), ("tcp", "tcp://"), ("modbus_tcp", "modbus-tcp://")]


def _truth(folder: Path, name: str) -> Path:
    text = Path(load_profile().path).read_text()
    for key, value in DIALECTS[name].items():
        shipped = getattr(load_profile().protocol, key)
        old = f"{key} = {str(shipped).lower()}"
        assert old in text, old
        text = text.replace(old, f"{key} = {str(value).lower()}", 1)
    path = folder / f"{name}.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module", params=list(DIALECTS))
def served(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, dict]]:
    """``c20sim serve`` of a drive with a changed dialect, on a line-timed pty, RTU over TCP and Modbus TCP."""
    folder = tmp_path_factory.mktemp("dialect")
    truth = _truth(folder, request.param)
    ready = folder / "ready.json"
    args = ("--pty", "--line-timing", "--tcp", "127.0.0.1:0", "--modbus-tcp", "127.0.0.1:0", "--no-audit")
    proc = subprocess.Popen(
        c20sim_command("serve", *args, "--profile", str(truth), "--ready-file", str(ready)),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        yield request.param, wait_for_ready_file(ready, proc)
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.parametrize(("port", "scheme"), LINKS)
def test_fit_learns_the_dialect_exercise_probes(
    served: tuple[str, dict[str, str]], tmp_path: Path, port: str, scheme: str
) -> None:
    name, ports = served
    out, fitted = tmp_path / "dialect.jsonl", tmp_path / "fitted.toml"
    done = c20sim_run("exercise", scheme + ports[port], "--dialect-only", "--out", str(out), cwd=tmp_path, timeout=120)
    assert done.returncode == 0, done.stderr
    notes = [r.note for r in load_frame_log(str(out)) if r.direction == "rx" and r.data]
    # the first read finds the drive (one line if none answers); every request after it the probe's, each noted
    assert notes[0] == "" and len(notes) > 100 and all(n.startswith("dialect ") for n in notes[1:])
    done = c20sim_run("fit", str(out), "--out", str(fitted), cwd=tmp_path, timeout=120)
    assert done.returncode == 0, done.stderr
    # the link told from the times of the probe's replies of two lengths (docs/fit.md, 'What each link adds')
    link = {"pty": "pty", "tcp": "device-server", "modbus_tcp": "gateway"}[port]
    assert f"  link: {link}, 19200 baud, 10-bit characters (replies of " in done.stdout, done.stdout
    protocol = tomllib.loads(fitted.read_text())["protocol"]
    expected = dict(DIALECTS[name])
    if port == "modbus_tcp":
        # a gateway makes the CRC: no bad frame reaches the drive, the quirk keeps the base's value, "not probed"
        expected["reply_to_bad_crc"] = True
        assert (
            "dialect reply_to_bad_crc      not learned  (base true) not written: not probed: over Modbus TCP the "
            "gateway makes the CRC and the length: a bad frame cannot be sent"
        ) in done.stdout
    assert {key: protocol[key] for key in expected} == expected, done.stdout
    lines = fitted.read_text().splitlines()
    for key in expected:
        if port == "modbus_tcp" and key == "reply_to_bad_crc":
            assert not any(line.startswith(f"{key} = ") and "capture" in line for line in lines)
        else:
            assert any(
                line.startswith(f"{key} = ") and '# source = "capture": dialect.jsonl line' in line for line in lines
            )
    assert "dialect exception_order       as c20sim" in done.stdout
    assert "dialect broadcast             silent" in done.stdout
    # the capture replayed against the fitted profile: every reply's bytes and exceptions the same
    replayed = c20sim_run("replay", str(out), "--profile", str(fitted), cwd=tmp_path)
    assert replayed.returncode == 0, replayed.stdout
    assert replayed.stdout.rstrip().endswith("replayed: every reply matches")
    # and against the shipped profile it differs: the probe's frames do tell the dialects apart
    shipped = c20sim_run("replay", str(out), cwd=tmp_path)
    assert shipped.returncode == 1, shipped.stdout


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (("read", "speed", "--dialect"), "--dialect: give --out FILE for the capture, and no action"),
        (("--dialect-only",), "--dialect: give --out FILE for the capture, and no action"),
        (("write", "setpoint", "100", "--dialect", "--out", "x.jsonl"), "--dialect: give --out FILE"),
    ],
)
def test_dialect_misuse_is_one_line(tmp_path: Path, args: tuple[str, ...], said: str) -> None:
    done = c20sim_run("exercise", "tcp://127.0.0.1:9", *args, cwd=tmp_path)
    assert said in one_line(done)
    assert not (tmp_path / "x.jsonl").exists()  # refused before the port is opened or the file written


def test_the_probe_then_the_programme_on_the_pty(served: tuple[str, dict[str, str]], tmp_path: Path) -> None:
    """exercise --dialect: the probe, then the programme, in one capture; fit learns the dialect and the physics;
    replay against the fitted profile differs in no probe request's reply."""
    name, ports = served
    out, fitted = tmp_path / "both.jsonl", tmp_path / "fitted.toml"
    args = ("--dialect", "--out", str(out), "--speeds", "1000,2000", "--hold", "1", "--rate", "20")
    done = c20sim_run("exercise", ports["pty"], *args, cwd=tmp_path, timeout=120)
    assert done.returncode == 0, done.stderr
    records = load_frame_log(str(out))
    notes = [r.note for r in records if r.direction == "rx" and r.data]
    probed = [n for n in notes if n.startswith("dialect ")]
    assert probed and notes.index(probed[-1]) < notes.index("", 1)  # the probe first, then the programme
    done = c20sim_run("fit", str(out), "--out", str(fitted), cwd=tmp_path, timeout=120)
    assert done.returncode == 0, done.stderr
    protocol = tomllib.loads(fitted.read_text())["protocol"]
    assert {key: protocol[key] for key in DIALECTS[name]} == DIALECTS[name], done.stdout
    assert any(line.startswith("  motor.kt_nm_per_a") and "+-" in line for line in done.stdout.splitlines())
    replayed = c20sim_run("replay", str(out), "--profile", str(fitted), cwd=tmp_path)
    by_line = {r.line: r.note for r in records}
    differing = [int(line.split()[2]) for line in replayed.stdout.splitlines() if line.startswith("  DIFF line ")]
    assert not [line for line in differing if by_line[line].startswith("dialect ")], replayed.stdout
