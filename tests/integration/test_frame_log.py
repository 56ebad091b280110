"""The frame log never holds up the wire: a reader that stops or exits, a full disk, a deleted file, rotation.

``c20sim serve --log-frames`` as a subprocess; a pymodbus master polls over
RTU over TCP meanwhile, and every poll must be answered. Whatever reaches the
log is whole JSON lines. The full-disk case needs a 5 MiB tmpfs, so root.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusIOException

from c20sim.wire.registers import Reg
from tests.conftest import wait_for_ready_file


def serve(tmp_path: Path, *args: str, stdout: int = subprocess.DEVNULL) -> tuple[subprocess.Popen[bytes], int]:
    proc, info = serve_info(tmp_path, *args, stdout=stdout)
    return proc, int(info["tcp"].rsplit(":", 1)[1])


def serve_info(tmp_path: Path, *args: str, stdout: int) -> tuple[subprocess.Popen[bytes], dict[str, str]]:
    ready = tmp_path / "ready.json"
    ready.unlink(missing_ok=True)
    command = [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--ready-file", str(ready), *args]
    command.append("--no-bus-timing")  # these tests fill logs with traffic: the volume, not the line's pace
    proc = subprocess.Popen(command, stdout=stdout, stderr=subprocess.PIPE)
    return proc, wait_for_ready_file(ready, proc)


def poll(port: int, seconds: float = 0.0, count: int = 0) -> tuple[int, int]:
    """Poll 2100H for ``seconds`` or ``count`` times, as fast as answers come; (asked, answered)."""
    client = ModbusTcpClient("127.0.0.1", port=port, framer=FramerType.RTU, timeout=2.0, retries=0)
    assert client.connect()
    asked = answered = 0
    end = time.monotonic() + seconds
    try:
        while (count and asked < count) or (seconds and time.monotonic() < end):
            asked += 1
            with contextlib.suppress(ModbusIOException):
                answered += not client.read_holding_registers(Reg.STATUS1, count=1, device_id=1).isError()
    finally:
        client.close()
    return asked, answered


def stop(proc: subprocess.Popen[bytes], timeout: float = 5.0) -> str:
    """SIGTERM; the process must be gone within ``timeout``; its stderr."""
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise AssertionError(f"SIGTERM not acted on within {timeout} s") from None
    assert proc.stderr is not None
    err = proc.stderr.read().decode()
    proc.stderr.close()
    return err


def whole_lines(*paths: Path) -> list[dict[str, object]]:
    records = []
    for path in paths:
        text = path.read_text()
        assert not text or text.endswith("\n"), f"{path}: the last line is cut: {text[-80:]!r}"
        for line in text.splitlines():
            records.append(json.loads(line))  # raises on a cut line
    return records


def log_dropped(url: str) -> int:
    with urllib.request.urlopen(url + "/frames?last=1", timeout=10) as answer:
        count: int = json.load(answer)["log_dropped"]
    return count


def test_a_reader_that_stops_reading_freezes_nothing(tmp_path: Path) -> None:
    # serve --log-frames /dev/stdout | (sleep 30): a pipe nobody reads, filled after about 64 KiB.
    options = ("--log-frames", "/dev/stdout", "--control", "127.0.0.1:0")
    proc, info = serve_info(tmp_path, *options, stdout=subprocess.PIPE)
    port = int(info["tcp"].rsplit(":", 1)[1])
    try:
        asked, answered = poll(port, seconds=8.0)
        assert answered == asked, f"{asked - answered} of {asked} polls unanswered while the log's reader slept"
        # Once the pipe (64 KiB) and the buffer (4,096 records) are full, records are dropped, and counted.
        deadline = time.monotonic() + 30
        while log_dropped(info["control"]) == 0:
            assert time.monotonic() < deadline, "no record dropped, yet the log's reader never read"
            more, answered = poll(port, count=200)
            assert answered == more
        err = stop(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        assert proc.stdout is not None
        proc.stdout.close()
    assert proc.returncode == 0, err
    assert "Traceback" not in err, err
    assert err.count("its buffer is full") == 1, err


def test_a_reader_that_exits_costs_one_line(tmp_path: Path) -> None:
    read_end, write_end = os.pipe()
    proc, port = serve(tmp_path, "--log-frames", "/dev/stdout", stdout=write_end)
    os.close(write_end)
    try:
        assert poll(port, count=20) == (20, 20)
        os.close(read_end)  # the reader exits
        asked, answered = poll(port, count=500)
        assert answered == asked, f"{asked - answered} of {asked} polls unanswered after the log's reader exited"
        err = stop(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "BrokenPipe" not in err, err
    assert err.count("the reader has gone") == 1, err


def test_rotation_keeps_three_old_files_of_whole_lines(tmp_path: Path) -> None:
    log = tmp_path / "frames.jsonl"
    proc, port = serve(tmp_path, "--log-frames", str(log), "--log-frames-max-mb", "0.01")
    try:
        assert poll(port, count=400) == (400, 400)
        deadline = time.monotonic() + 10
        while not Path(f"{log}.3").exists():
            assert time.monotonic() < deadline, sorted(p.name for p in tmp_path.iterdir())
            time.sleep(0.01)
        err = stop(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    names = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("frames"))
    assert names == ["frames.jsonl", "frames.jsonl.1", "frames.jsonl.2", "frames.jsonl.3"]
    files = [log, *(Path(f"{log}.{i}") for i in (1, 2, 3))]
    assert all(f.stat().st_size <= 10485 for f in files), [f.stat().st_size for f in files]
    assert whole_lines(*files)


def test_a_deleted_log_file_is_started_again(tmp_path: Path) -> None:
    log = tmp_path / "frames.jsonl"
    proc, port = serve(tmp_path, "--log-frames", str(log))
    try:
        assert poll(port, count=10) == (10, 10)
        deadline = time.monotonic() + 5
        while not log.exists() or log.stat().st_size == 0:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        log.unlink()
        deadline = time.monotonic() + 10
        while not log.exists():  # the writer checks its path at most once a second
            assert poll(port, count=5) == (5, 5)
            assert time.monotonic() < deadline, "the deleted log was not started again"
        err = stop(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert err.count("the file was deleted or replaced; writing a new one") == 1, err
    assert whole_lines(log)


@pytest.fixture
def small_tmpfs(tmp_path: Path) -> Iterator[Path]:
    """A 5 MiB tmpfs, mounted for the test (root only)."""
    mount = tmp_path / "small"
    mount.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a 5 MiB tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=5m", "tmpfs", str(mount)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def test_a_full_disk_keeps_whole_lines_and_logging_resumes(tmp_path: Path, small_tmpfs: Path) -> None:
    log, filler = small_tmpfs / "frames.jsonl", small_tmpfs / "filler"
    proc, port = serve(tmp_path, "--log-frames", str(log))
    try:
        assert poll(port, count=50) == (50, 50)
        fd = os.open(filler, os.O_WRONLY | os.O_CREAT)  # fill the disk to the last byte
        try:
            with contextlib.suppress(OSError):
                while os.write(fd, b"\0" * 4096):
                    pass
            with contextlib.suppress(OSError):
                while os.write(fd, b"\0"):
                    pass
        finally:
            os.close(fd)
        asked, answered = poll(port, count=500)
        assert answered == asked, f"{asked - answered} of {asked} polls unanswered on a full disk"
        assert whole_lines(log)
        filler.unlink()
        assert poll(port, count=50) == (50, 50)
        deadline = time.monotonic() + 10
        while not any(r.get("kind") == "log-dropped" for r in whole_lines(log)):
            assert time.monotonic() < deadline, "logging did not resume once space was freed"
            assert poll(port, count=5) == (5, 5)
        err = stop(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    records = whole_lines(log)
    notice = next(r for r in records if r.get("kind") == "log-dropped")
    assert isinstance(notice["dropped"], int) and notice["dropped"] > 0, notice
    assert records[-1].get("kind") != "log-dropped"  # frames were written after the notice
    assert "Traceback" not in err, err
    assert err.count("frames are dropped and counted") == 1 and err.count("writing again;") == 1, err


@pytest.mark.parametrize(("option", "rotated"), [((), True), (("--log-frames-max-mb", "0"), False)])
def test_the_log_is_bounded_unless_asked(tmp_path: Path, option: tuple[str, ...], rotated: bool) -> None:
    """Without --log-frames-max-mb the log is rotated at 100 MiB (before: it grew without end, about 10 MB a
    minute on a busy line); --log-frames-max-mb 0 asks for no bound. A log of 100 MiB already there (sparse)
    stands for the hours it takes a line to write one."""
    log = tmp_path / "frames.jsonl"
    with open(log, "wb") as f:
        f.truncate(100 * 1024 * 1024)
    proc, port = serve(tmp_path, "--log-frames", str(log), *option)
    try:
        assert poll(port, count=20) == (20, 20)
        deadline = time.monotonic() + 10
        while log.stat().st_size in (0, 100 * 1024 * 1024):  # the writer thread has written nothing yet
            assert time.monotonic() < deadline, "nothing logged"
            time.sleep(0.01)
        err = stop(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0 and "Traceback" not in err, err
    old = Path(f"{log}.1")
    if rotated:
        assert old.stat().st_size == 100 * 1024 * 1024
        assert 0 < log.stat().st_size < 1024 * 1024 and whole_lines(log)
    else:
        assert not old.exists()
        assert log.stat().st_size > 100 * 1024 * 1024
