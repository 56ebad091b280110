"""SIGKILL during a stream of EEPROM writes: the state file always loads and keeps every acknowledged write.

``c20sim serve --state PATH`` runs as a subprocess; a client writes 2003H
(acceleration time, the mirror of F00.11, which the drive keeps in its
EEPROM) with increasing values, and the server is killed at a seeded point:
between two writes, or with a write in flight. The file is then loaded the way
the drive loads it. It must hold the last acknowledged value, or the one in
flight (which may have landed before the kill), and nothing else.

``bench/kill.py`` runs many more kill points.
"""

from __future__ import annotations

import os
import random
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from c20sim.drive.model import Drive
from c20sim.drive.profile import load_profile
from c20sim.wire.protocol import WriteSingleRequest, encode
from c20sim.wire.registers import Reg, parse_fcode
from tests.conftest import wait_for_ready_file

#: F00.11, acceleration time: 1-6000, mirrored by 2003H, kept in the EEPROM.
FCODE = parse_fcode("F00.11")
#: The first value written: far from the default (5), so a lost write cannot pass for a kept one.
FIRST = 100


@dataclass
class Outcome:
    acknowledged: int  #: the last value whose reply came back
    sent: int  #: the last value sent
    stored: int  #: what the state file holds after the kill
    leftovers: int  #: temporary files the kill left beside the state file


def _start(state: Path, ready: Path) -> subprocess.Popen[bytes]:
    command = [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--state", str(state)]
    command += ["--ready-file", str(ready), "--clock", "virtual"]
    return subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _write(sock: socket.socket, value: int) -> bool:
    """Write 2003H = value; True when the echo came back."""
    request = encode(WriteSingleRequest(1, Reg.ACCEL_TIME, value))
    sock.sendall(request)
    reply = b""
    while len(reply) < len(request):
        chunk = sock.recv(64)
        if not chunk:
            return False
        reply += chunk
    assert reply == request, f"write {value}: reply {reply.hex(' ')}"
    return True


def kill_once(workdir: Path, seed: int, *, max_writes: int = 40) -> Outcome:
    """Start, stream writes, SIGKILL at a point chosen by ``seed``, load the state file."""
    rng = random.Random(seed)
    workdir.mkdir(parents=True, exist_ok=True)
    state, ready = workdir / "drive.json", workdir / "ready.json"
    for stale in (state, ready):
        stale.unlink(missing_ok=True)
    proc = _start(state, ready)
    acknowledged = sent = 0
    try:
        port = int(wait_for_ready_file(ready, proc, timeout=20.0)["tcp"].rsplit(":", 1)[1])
        writes_before_kill = rng.randint(1, max_writes)
        in_flight = rng.random() < 0.7
        spin = rng.random() * 0.003  # with a write in flight: kill 0-3 ms after sending it
        with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            for value in range(FIRST, FIRST + writes_before_kill):
                sent = value
                assert _write(sock, value)
                acknowledged = value
            if in_flight:
                sent += 1
                sock.sendall(encode(WriteSingleRequest(1, Reg.ACCEL_TIME, sent)))
                until = time.perf_counter() + spin
                while time.perf_counter() < until:
                    pass
            proc.send_signal(signal.SIGKILL)
            proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if proc.stderr is not None:
            proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL
    profile = load_profile()
    drive = Drive(profile, state_path=state)  # raises StateFileError if the file does not load
    stored = drive.read(FCODE)
    assert drive.read(profile.registers.canonical(Reg.ACCEL_TIME)) == stored  # 2003H reads F00.11
    leftovers = sum(1 for name in os.listdir(workdir) if name.startswith(f".{state.name}.") and name.endswith(".tmp"))
    return Outcome(acknowledged, sent, stored, leftovers)


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_sigkill_keeps_every_acknowledged_write(tmp_path: Path, seed: int) -> None:
    outcome = kill_once(tmp_path, seed)
    assert outcome.acknowledged >= FIRST
    # the last acknowledged value, or the one in flight if it landed before the kill; nothing else
    assert outcome.stored in {outcome.acknowledged, outcome.sent}, outcome
