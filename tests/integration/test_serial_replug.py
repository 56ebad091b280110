"""A serial port that goes away (an adapter unplugged) is reported once and served again when it is back.

The "adapter" is a pty pair behind a symlink: ``c20sim serve --serial LINK``
opens the pty's slave side through the link as pyserial opens any port, and
the test is the master on the other side. Unplugging closes the pty (the
port then reads EIO, as an unplugged USB adapter does); replugging points
the link at a fresh pty, as udev's by-id links do.
"""

from __future__ import annotations

import os
import select
import subprocess
import sys
import time
import tty
from pathlib import Path

from c20sim.wire.protocol import ReadRequest, ReadResponse, encode
from c20sim.wire.registers import Reg
from tests.conftest import wait_for_ready_file

ASK = encode(ReadRequest(1, Reg.STATUS1, 1))
ANSWER = encode(ReadResponse(1, (3,)))


def plug(link: Path) -> tuple[int, int]:
    """A new "adapter": a pty pair, the link pointing at its slave; returns (master, slave) fds."""
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    tmp = link.with_name(link.name + ".new")
    tmp.unlink(missing_ok=True)
    tmp.symlink_to(os.ttyname(slave))
    os.replace(tmp, link)
    return master, slave


def ask(master: int, timeout: float = 1.0) -> bytes:
    os.write(master, ASK)
    data = b""
    deadline = time.monotonic() + timeout
    while len(data) < len(ANSWER) and select.select([master], [], [], max(0.0, deadline - time.monotonic()))[0]:
        data += os.read(master, 64)
    return data


def test_an_unplugged_port_is_served_again_when_it_is_back(tmp_path: Path) -> None:
    link, ready = tmp_path / "ttyUSB-c20", tmp_path / "ready.json"
    master, slave = plug(link)
    command = [sys.executable, "-m", "c20sim", "serve", "--serial", str(link), "--ready-file", str(ready)]
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        wait_for_ready_file(ready, proc)
        assert ask(master) == ANSWER
        os.close(slave)
        os.close(master)  # unplugged: the port reads EIO
        master, slave = plug(link)  # replugged
        deadline = time.monotonic() + 10
        while (reply := ask(master, timeout=0.5)) != ANSWER:
            assert proc.poll() is None, "the server exited when its only port went away"
            assert time.monotonic() < deadline, f"not served again after replugging (read {reply.hex(' ')})"
    finally:
        proc.terminate()  # before the pty goes: that would be another unplug
        _out, err = proc.communicate(timeout=10)
        os.close(master)
        os.close(slave)
    assert proc.returncode == 0, err
    assert "Traceback" not in err, err
    lost = [line for line in err.splitlines() if "lost" in line]
    back = [line for line in err.splitlines() if "is back; serving it again" in line]
    assert len(lost) == 1 and len(back) == 1, err
