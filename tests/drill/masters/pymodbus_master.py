"""A reference master for the drill's tests on pymodbus (its sync client), in three styles.

    python pymodbus_master.py careful|naive|stormy --tcp HOST:PORT | --modbus-tcp HOST:PORT | --pty PATH

As the raw master (raw_master.py), every 100 ms, drive 1:

- careful: pymodbus's own 3 retries, a 250 ms timeout (2 s over Modbus TCP, beyond the gateway's 1 s), and 3
  more on a gateway's 0x0B or a 0x06; polls 2100H and 3006H, backs off while the drive is
  silent; on a fault reads 2102H, sends no run command, resets once (not again for 3 s); a drive found stopped
  gets 2001H again, then the run command. On the first sight of a fault it reads the fault record (F07.27,
  F07.33, F07.36, F07.37) and the automatic reset (F08.28, F08.29): while the drive will reset itself, its own
  reset waits for F08.29 and 0.5 s more.
- naive: no retries (retries=0), a 250 ms timeout; polls 3006H and writes 2000H = 1 every cycle, an error is
  ignored; never reads the status or fault code, never writes 2001H again.
- stormy: no pause and no bound: a request that fails is sent again at once, with a 30 ms timeout.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import time

from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

PERIOD = 0.1
#: read on the first sight of a fault (as raw_master.py): the record, then F08.28 and F08.29
RECORD = (0x071B, 0x0721, 0x0724, 0x0725)
AUTO_TRIALS, AUTO_INTERVAL = 0x081C, 0x081D


def client(args: argparse.Namespace, timeout: float, retries: int) -> ModbusTcpClient | ModbusSerialClient:
    if args.pty:
        return ModbusSerialClient(args.pty, framer=FramerType.RTU, baudrate=19200, timeout=timeout, retries=retries)
    host, port = (args.tcp or args.modbus_tcp).rsplit(":", 1)
    framer = FramerType.RTU if args.tcp else FramerType.SOCKET
    return ModbusTcpClient(host, port=int(port), framer=framer, timeout=timeout, retries=retries)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("style", choices=("careful", "naive", "stormy"))
    parser.add_argument("--tcp")
    parser.add_argument("--modbus-tcp")
    parser.add_argument("--pty")
    args = parser.parse_args()
    logging.disable(logging.CRITICAL)  # pymodbus logs every timeout
    style = args.style
    # over Modbus TCP a timeout longer than the gateway's (serve --gateway-timeout, 1 s): its 0x0B then answers
    # a silent drive, and a retry under the same transaction id cannot take the first try's late 0x0B as its own
    # answer (with both at 1 s the two raced: a retry 6 ms after its 0x0B, judged a storm)
    timeout = 0.03 if style == "stormy" else 2.0 if args.modbus_tcp and style == "careful" else 0.25
    c = client(args, timeout, 3 if style == "careful" else 0)
    c.connect()

    def read(register: int) -> int | None:
        tries = 0
        while True:
            try:
                r = c.read_holding_registers(register, count=1, device_id=1)
                if not r.isError():
                    return int(r.registers[0])
                # a gateway's "no answer" (0x0B) or a garbled request (0x06): careful asks again, 3 times at most
                again = style == "careful" and getattr(r, "exception_code", 0) in (0x06, 0x0B) and tries < 3
            except Exception:  # a timeout, a broken reply: pymodbus raises (after its own retries)
                again = False
            tries += 1
            if style != "stormy" and not again:
                return None

    def write(register: int, value: int) -> None:
        while True:
            try:
                r = c.write_register(register, value, device_id=1)
                if not r.isError() or style != "stormy":
                    return
            except Exception:
                if style != "stormy":
                    return

    write(0x2001, 1500)
    write(0x2000, 1)
    next_reset = 0.0
    fault_seen = False
    silent = 0
    cycle = time.monotonic()
    while True:
        if style == "naive":
            read(0x3006)
            write(0x2000, 1)
        else:
            status = read(0x2100)
            speed = read(0x3006)
            if status is None and speed is None:
                silent += 1
                time.sleep(min(0.4, 0.1 * 2**silent))
            else:
                silent = 0
            if status == 4:
                read(0x2102)
                if not fault_seen:
                    fault_seen = True
                    for register in RECORD:
                        read(register)
                    trials, interval = read(AUTO_TRIALS), read(AUTO_INTERVAL)
                    if trials and interval is not None:
                        next_reset = max(next_reset, time.monotonic() + interval / 10 + 0.5)
                if time.monotonic() >= next_reset:
                    write(0x2000, 7)
                    next_reset = time.monotonic() + 3.0
            elif status is not None:
                fault_seen = False
            if status == 3:
                write(0x2001, 1500)
                write(0x2000, 1)
        cycle += PERIOD
        pause = cycle - time.monotonic()
        if pause > 0:
            time.sleep(pause)
        else:
            cycle = time.monotonic()


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):
        main()
