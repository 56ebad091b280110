"""A pty master that goes away leaves nothing behind for the next one, as a real port loses what it is sent.

``c20sim serve --pty`` as a subprocess. A master writes a burst of requests
and closes without reading; the next program opens the device without
flushing (as libmodbus and mbpoll do) and asks one question: every reply it
reads must be the answer to its own question. It may lose its first request
if it opened while the server was still dropping what the old master left
(it then asks again); it must never read an old master's answer.

With ``--line-timing`` a reply is paced out byte by byte on a thread of its
own: a master that closes while its reply is on the way must leave no byte of
it behind either.
"""

from __future__ import annotations

import contextlib
import os
import select
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from c20sim.wire.protocol import ReadRequest, ReadResponse, WriteSingleRequest, encode
from c20sim.wire.registers import Reg
from tests.conftest import wait_for_ready_file

OLD = encode(ReadRequest(1, Reg.SPEED_SETPOINT, 1))  # the old master's question: 2001H (reads 1500)
ASK = encode(ReadRequest(1, Reg.STATUS1, 1))  # the new master's question: 2100H
ANSWER = encode(ReadResponse(1, (3,)))  # 2100H of a stopped drive: 3


@pytest.fixture
def pty(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[str]:
    ready = tmp_path / "ready.json"
    command = [sys.executable, "-m", "c20sim", "serve", "--pty", "--ready-file", str(ready)]
    command += getattr(request, "param", [])
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        path = wait_for_ready_file(ready, proc)["pty"]
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, encode(WriteSingleRequest(1, Reg.SPEED_SETPOINT, 1500)))
            assert read_reply(fd, 8) is not None
        finally:
            os.close(fd)
        yield path
    finally:
        proc.kill()
        proc.wait()
        assert proc.stderr is not None
        proc.stderr.close()


def read_reply(fd: int, length: int, timeout: float = 10.0) -> bytes | None:
    data = b""
    deadline = time.monotonic() + timeout
    while len(data) < length:
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            return None
        with contextlib.suppress(BlockingIOError):  # flushed between the select and the read
            data += os.read(fd, length - len(data))
    return data


#: Times a master asks before it gives up: a busy machine only makes it ask again, and a server that answers at
#: all answers long before the last (each ask waits a second; a reply takes milliseconds).
ASKS = 30

#: The next program: opens the device without flushing, asks 2100H (again after a 1 s timeout, up to ASKS
#: times), prints the reply it read in hex and how many times it had to ask again.
NEXT_MASTER = f"""
import os, select, sys, time
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)
for retry in range({ASKS}):
    os.write(fd, bytes.fromhex("{ASK.hex()}"))
    data, deadline = b"", time.monotonic() + 1.0
    while len(data) < {len(ANSWER)} and select.select([fd], [], [], max(0.0, deadline - time.monotonic()))[0]:
        data += os.read(fd, {len(ANSWER)} - len(data))
    if len(data) == {len(ANSWER)}:
        break
print(data.hex(" "), retry)
"""


def next_masters_after(pty: str, old_master: Callable[[int, int], None]) -> None:
    """20 trials: ``old_master(fd, trial)`` talks on the device and it is closed; then the next program asks.
    Every reply the next programs read must be the answer to their own question."""
    wrong: list[str] = []
    retries = 0
    for trial in range(20):
        old = os.open(pty, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            old_master(old, trial)
        finally:
            os.close(old)
        done = subprocess.run(
            [sys.executable, "-c", NEXT_MASTER, pty], capture_output=True, text=True, timeout=ASKS + 30, check=True
        )
        reply, again = done.stdout.rsplit(" ", 1)
        retries += int(again)
        if reply != ANSWER.hex(" "):
            wrong.append(f"trial {trial}: read {reply!r}")
    assert not wrong, f"{len(wrong)} of 20 programs read an old master's reply ({retries} retries): {wrong[:3]}"


def test_the_next_master_never_reads_an_old_masters_replies(pty: str) -> None:
    def burst(fd: int, trial: int) -> None:
        # Opened just after the last program closed, its burst may be dropped whole with what that program left
        # (the slower the machine, the likelier): it asks again, as any master does after a timeout.
        for _ in range(ASKS):
            os.write(fd, OLD * (20 + trial))
            if read_reply(fd, 7, timeout=1.0) is not None:
                return  # an answer came: more are on their way; gone without them
        pytest.fail(f"trial {trial}: no reply to the old master's burst in {ASKS} tries of 1 s")

    next_masters_after(pty, burst)


@pytest.mark.parametrize("pty", [["--line-timing"]], indirect=True)
def test_a_line_timed_reply_cut_off_by_a_close_leaves_no_byte_behind(pty: str) -> None:
    def cut_off(fd: int, trial: int) -> None:
        # Its reply has begun (paced at 0.52 ms a byte at 19200, 3.6 ms for 7 bytes): close in the middle.
        # Asked again after a timeout, as the next master does: opened just after the last program closed,
        # it may lose its request with what that program left.
        for _ in range(ASKS):
            os.write(fd, OLD)
            if read_reply(fd, 1 + trial % 4, timeout=1.0) is not None:
                return
        pytest.fail(f"trial {trial}: no reply to the old master in {ASKS} tries of 1 s")

    next_masters_after(pty, cut_off)


@pytest.mark.parametrize("pty", [[], ["--line-timing"]], indirect=True)
def test_the_next_master_never_reads_replies_to_a_master_that_wrote_all_it_could_and_never_read(pty: str) -> None:
    """The old master writes requests until the device takes no more (every buffer between it and the server
    full, replies piling up unread) and closes: before, the next master read 3,185 bytes of its replies."""

    def flood(fd: int, trial: int) -> None:
        burst = OLD * 512
        deadline = time.monotonic() + 0.2 + 0.01 * trial
        while time.monotonic() < deadline:
            try:
                os.write(fd, burst)
            except BlockingIOError:
                select.select([], [fd], [], 0.01)

    next_masters_after(pty, flood)
