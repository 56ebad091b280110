"""A SCADA master that speaks Modbus TCP, on its first try: the default endpoints include Modbus TCP, a Modbus TCP
master at the RTU-over-TCP port is told where to go (once: the log, stderr, the notices), and the frame log keeps
what the TCP connection carried (MBAP frames), which decode and replay read."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusIOException

from c20sim.cli import DEFAULT_MODBUS_TCP, DEFAULT_TCP
from c20sim.testing import C20Sim
from tests.conftest import DEFAULT_PORT_TAKEN, wait_for_ready_file
from tests.integration.conftest import c20sim_command, get, stop


def serve(procs: list[subprocess.Popen[str]], *args: str) -> subprocess.Popen[str]:
    proc = subprocess.Popen(c20sim_command("serve", *args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    procs.append(proc)
    return proc


def host_port(text: str) -> tuple[str, int]:
    host, port = text.rsplit(":", 1)
    return host, int(port)


@pytest.mark.serial  # the default ports: no other test may hold them meanwhile
def test_the_default_endpoints_include_modbus_tcp_on_1502(tmp_path: Path, procs: list[subprocess.Popen[str]]) -> None:
    """Bare ``c20sim serve``: a pty, RTU over TCP on 5020, and Modbus TCP on 1502, all in the ready line."""
    ready = tmp_path / "ready.json"
    proc = serve(procs, "--ready-file", str(ready))
    try:
        info = wait_for_ready_file(ready, proc)
    except AssertionError as exc:
        if "the port is in use" in str(exc):  # a fixed port: another simulator on this machine holds it
            pytest.skip(f"{DEFAULT_PORT_TAKEN}: {exc}")
        raise
    assert (
        (info["tcp"], info["modbus_tcp"]) == (DEFAULT_TCP, DEFAULT_MODBUS_TCP) == ("127.0.0.1:5020", "127.0.0.1:1502")
    )
    assert info["pty"].startswith("/dev/")
    client = ModbusTcpClient("127.0.0.1", port=1502, timeout=2, retries=0)  # framer: Modbus TCP, pymodbus's default
    assert client.connect()
    try:
        reply = client.read_holding_registers(0x2100, count=1, device_id=1)
        assert not reply.isError(), reply
        assert reply.registers == [3]  # status word 1: stopped
    finally:
        client.close()
    out, _ = stop(proc)
    assert out.splitlines()[0] == (
        f"c20sim ready: c20-400hr, drives 1, realtime clock; pty {info['pty']}; tcp 127.0.0.1:5020; "
        "modbus_tcp 127.0.0.1:1502"
    )


def test_a_modbus_tcp_master_at_the_rtu_port_gets_silence_and_one_word_where_to_go(
    tmp_path: Path, procs: list[subprocess.Popen[str]]
) -> None:
    ready, log = tmp_path / "ready.json", tmp_path / "frames.jsonl"
    proc = serve(
        procs,
        "--tcp",
        "127.0.0.1:0",
        "--modbus-tcp",
        "127.0.0.1:0",
        "--control",
        "127.0.0.1:0",
        "--log-frames",
        str(log),
        "--ready-file",
        str(ready),
    )
    info = wait_for_ready_file(ready, proc)
    host, port = host_port(info["tcp"])
    master = ModbusTcpClient(host, port=port, timeout=0.3, retries=0)  # Modbus TCP, at the RTU port
    assert master.connect()
    try:
        for _ in range(3):
            with pytest.raises(ModbusIOException, match="No response received"):
                master.read_holding_registers(0x2100, count=1, device_id=1)
    finally:
        master.close()
    # the same port still serves an RTU master
    rtu = ModbusTcpClient(host, port=port, framer=FramerType.RTU, timeout=2, retries=0)
    assert rtu.connect()
    try:
        assert rtu.read_holding_registers(0x2100, count=1, device_id=1).registers == [3]
    finally:
        rtu.close()
    said = f"RTU over TCP {info['tcp']}: this looks like Modbus TCP: use --modbus-tcp (open on {info['modbus_tcp']})"
    telemetry = get(info["control"] + "/telemetry")
    assert telemetry["notices"] == [said]
    frames = get(info["control"] + "/frames")["frames"]
    assert isinstance(frames, list)
    noise = [f for f in frames if f["kind"] == "noise"]
    assert [(f["hex"], f["text"]) for f in noise] == [
        (
            f"00 0{n} 00 00 00 06 01 03 21 00 00 01",
            f"Modbus TCP (MBAP) on the RTU-over-TCP port: transaction {n}, unit 1: not answered",
        )
        for n in (1, 2, 3)
    ]
    _, err = stop(proc)
    assert err == f"c20sim: {said}; this port answers no Modbus TCP frame, as a drive would not\n"  # once
    assert [json.loads(line)["kind"] for line in log.read_text().splitlines()] == [
        "noise",
        "noise",
        "noise",
        "request",
        "reply",
    ]


def test_the_frame_log_keeps_the_mbap_frames_and_decode_and_replay_read_them(
    tmp_path: Path, procs: list[subprocess.Popen[str]]
) -> None:
    ready, log = tmp_path / "ready.json", tmp_path / "frames.jsonl"
    proc = serve(
        procs,
        "--modbus-tcp",
        "127.0.0.1:0",
        "--control",
        "127.0.0.1:0",
        "--log-frames",
        str(log),
        "--ready-file",
        str(ready),
    )
    info = wait_for_ready_file(ready, proc)
    host, port = host_port(info["modbus_tcp"])
    client = ModbusTcpClient(host, port=port, timeout=3, retries=0)
    assert client.connect()
    try:
        assert client.write_register(0x2001, 1500, device_id=1).registers == [1500]
        absent = client.read_holding_registers(0x2100, count=1, device_id=9)  # no drive 9: the gateway's 0x0B
        assert (absent.isError(), absent.exception_code) == (True, 0x0B)
    finally:
        client.close()
    frames = get(info["control"] + "/frames")["frames"]
    assert isinstance(frames, list)
    keys = ("dir", "hex", "modbus_tcp", "rtu", "kind", "slave")
    api = [{k: v for k, v in f.items() if k in keys} for f in frames]
    stop(proc)
    ids = [f["modbus_tcp"]["transaction"] for f in api]
    first, second = ids[0], ids[2]
    expected = [
        {
            "dir": "rx",
            "hex": f"{first >> 8:02X} {first & 0xFF:02X} 00 00 00 06 01 06 20 01 05 DC",
            "modbus_tcp": {"transaction": first, "unit": 1},
            "rtu": "01 06 20 01 05 DC D1 03",
            "kind": "request",
            "slave": 1,
        },
        {
            "dir": "tx",
            "hex": f"{first >> 8:02X} {first & 0xFF:02X} 00 00 00 06 01 06 20 01 05 DC",
            "modbus_tcp": {"transaction": first, "unit": 1},
            "rtu": "01 06 20 01 05 DC D1 03",
            "kind": "reply",
            "slave": 1,
        },
        {
            "dir": "rx",
            "hex": f"{second >> 8:02X} {second & 0xFF:02X} 00 00 00 06 09 03 21 00 00 01",
            "modbus_tcp": {"transaction": second, "unit": 9},
            "rtu": "09 03 21 00 00 01 8F 7E",
            "kind": "request",
            "slave": 9,
        },
        {
            "dir": "tx",
            "hex": f"{second >> 8:02X} {second & 0xFF:02X} 00 00 00 03 09 83 0B",
            "modbus_tcp": {"transaction": second, "unit": 9},
            "rtu": None,
            "kind": "exception",
            "slave": 9,
        },
    ]
    assert api == expected
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    assert [{k: v for k, v in f.items() if k in expected[0]} for f in logged] == expected
    decoded = subprocess.run(c20sim_command("decode", "-f", str(log)), capture_output=True, text=True, timeout=60)
    assert (decoded.returncode, decoded.stderr) == (0, "")
    words = [line for line in decoded.stdout.splitlines() if not re.match(r"^ *\d+\.\d{6} (rx|tx) ", line)]
    assert words == [
        f"  modbus tcp: transaction {first}, unit 1; on the line: 01 06 20 01 05 DC D1 03",
        "  request: slave 1: write 2001H = 05DC: 1500 rpm",
        f"  modbus tcp: transaction {first}, unit 1; on the line: 01 06 20 01 05 DC D1 03",
        "  reply: slave 1: write 2001H = 05DC: 1500 rpm",
        f"  modbus tcp: transaction {second}, unit 9; on the line: 09 03 21 00 00 01 8F 7E",
        "  request: slave 9: read 2100H (status word 1)",
        f"  modbus tcp: transaction {second}, unit 9; not on the line: the gateway's own answer",
        "  gateway: exception 0x0B to function 0x03: gateway target device failed to respond",
    ]
    replayed = subprocess.run(c20sim_command("replay", str(log)), capture_output=True, text=True, timeout=60)
    assert (replayed.returncode, replayed.stderr) == (0, "")
    assert replayed.stdout.splitlines()[-1] == "2 replayed: every reply matches"


@pytest.mark.c20sim(transport="modbus-tcp")
def test_a_reply_the_line_corrupted_is_logged_unforwarded_then_the_gateways_0x0B(c20sim: C20Sim) -> None:
    """What the TCP connection carried, record by record: the request, nothing for the broken reply (its RTU bytes
    beside, and why), then the gateway's own exception 0x0B."""
    c20sim.link_faults(corrupt_crc=True)
    client = ModbusTcpClient("127.0.0.1", port=c20sim.modbus_tcp_port, timeout=3, retries=0)
    assert client.connect()
    try:
        reply = client.read_holding_registers(0x2100, count=1, device_id=1)
    finally:
        client.close()
    assert (reply.isError(), reply.exception_code) == (True, 0x0B)
    records = [r.as_dict() for r in c20sim.frames()]
    tid = reply.transaction_id
    header = {"transaction": tid, "unit": 1}
    assert [(r["dir"], r["kind"], r["hex"], r["modbus_tcp"], r["rtu"] is None) for r in records] == [
        ("rx", "request", f"{tid >> 8:02X} {tid & 0xFF:02X} 00 00 00 06 01 03 21 00 00 01", header, False),
        ("tx", "reply", "", header, False),
        ("tx", "exception", f"{tid >> 8:02X} {tid & 0xFF:02X} 00 00 00 03 01 83 0B", header, True),
    ]
    assert records[0]["rtu"] == "01 03 21 00 00 01 8E 36"
    assert str(records[1]["rtu"]).startswith("01 03 02 00 03 ")  # the reply, with a broken CRC
    assert records[1]["note"].endswith("the gateway forwards no broken reply: it answers 0x0B after its timeout")
