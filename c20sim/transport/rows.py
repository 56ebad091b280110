"""The transports, one row each: its options, opener, ready-file key, POSIX need, line model and help.

Every front end is built from these rows: ``serve`` opens the rows whose
options were given (in the rows' order) and writes each one's address under
its key in the ready file; the command line's endpoint options, the
dashboard's session (which passes them on to the serve it starts), the test
handle's ``transport=`` words and its pytest plugin, and the plant's
container ports all iterate :func:`rows`. A new transport is one
:class:`Transport` given to :func:`register` (which returns what removes it
again); no front end names a transport.

The line model says what the master's connection carries: ``rtu`` (Modbus
RTU frames, as on the RS485 line: a pty, a serial port, a serial device
server's TCP port) or ``mbap`` (Modbus TCP, a gateway in front of the line).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal, Protocol

from ..wire.errors import C20SimError
from .line import Line

__all__ = [
    "NEEDS_POSIX",
    "Endpoint",
    "NetworkEndpoint",
    "Opening",
    "Option",
    "PlantPort",
    "Transport",
    "find",
    "posix_supported",
    "register",
    "rows",
]

#: What the line model of a transport is: RTU frames, or Modbus TCP's MBAP frames (see the module's text).
LineModel = Literal["rtu", "mbap"]

#: What ``--pty`` says where there are no ptys (Windows): tty and termios are POSIX-only.
NEEDS_POSIX = (
    "--pty needs a POSIX system (Linux, macOS, BSD); on Windows use a com0com pair with --serial COMn, "
    "or --tcp HOST:PORT (RTU over TCP) or --modbus-tcp HOST:PORT"
)


def posix_supported() -> bool:
    """True where a pty can be made (POSIX: the tty module loads); False on Windows."""
    try:
        import tty  # noqa: F401
    except ImportError:
        return False
    return True


class Endpoint(Protocol):
    """What serve does with an opened transport: start it, read its address, close it."""

    @property
    def name(self) -> str: ...  #: its address: the ready file's value (a path, or HOST:PORT)

    async def start(self) -> None: ...

    def close(self) -> None: ...


class NetworkEndpoint(Endpoint, Protocol):
    """A listening transport: its real host and port once started, and an end to wait for."""

    host: str
    port: int

    async def wait_closed(self) -> None: ...


@dataclass(frozen=True)
class Option:
    """One command-line option of a transport: ``--flag VALUE``, or an on/off switch where ``metavar`` is None."""

    flag: str
    help: str
    metavar: str | None = None

    @property
    def dest(self) -> str:
        """Its name in the parsed arguments, serve's options and the dashboard's session (``--modbus-tcp``:
        ``modbus_tcp``)."""
        return self.flag.removeprefix("--").replace("-", "_")


@dataclass(frozen=True)
class Opening:
    """What an opener is given: the shared line, its own options' values (by dest), and serve's line settings."""

    line: Line
    values: Mapping[str, Any]
    parity: str = "N"
    stopbits: int = 1
    line_timing: bool = False
    max_connections: int | None = None
    gateway_timeout: float = 1.0


@dataclass(frozen=True)
class PlantPort:
    """How a plant's pod serves a network transport (c20sim.plant): its port inside the container, the
    Service's port, the option that places bus i's host port at BASE+i, and its name in words."""

    name: str  #: the Kubernetes port name (at most 15 characters)
    container_port: int
    service_port: int
    base_option: str
    title: str


@dataclass(frozen=True)
class Transport:
    """One transport: what every front end needs to know of it."""

    name: str  #: its word in the test handle (``transport="modbus-tcp"``) and the plugin's fixture
    key: str  #: its key in the ready file (and serve's ready line)
    options: tuple[Option, ...]  #: the first is the one that asks for it; the others refine it
    opener: Callable[[Opening], Endpoint]  #: makes the endpoint (not started): serve starts it
    model: LineModel
    help: str  #: one line: what the transport is
    #: None where it works everywhere; else what to say where there is no POSIX (it needs ptys)
    posix_only: str | None = None
    #: a listener (its endpoint is a :class:`NetworkEndpoint`): ``--max-connections`` and ``--gateway-timeout``
    network: bool = False
    #: what a bare ``c20sim serve`` gives its first option (None: not opened without being asked for)
    default: str | bool | None = None
    #: what the test handle gives its first option (port 0; True for a switch); None: the handle cannot open it
    fixture: str | bool | None = None
    #: how a plant's pod serves it (None: not in a plant: no device in a container)
    plant: PlantPort | None = None
    #: told, once every endpoint has started, where the others are (a key's address, or None): for the word to
    #: a master that came to the wrong port
    introduce: Callable[[Endpoint, Callable[[str], str | None]], None] | None = None

    def asked(self, values: Mapping[str, Any]) -> bool:
        """Was it asked for: any of its options given (``--link`` alone asks for a pty)?"""
        return any(values.get(option.dest) for option in self.options)

    def usable(self) -> bool:
        """Can it be opened on this system (a pty needs POSIX)?"""
        return self.posix_only is None or posix_supported()


def _open_pty(opening: Opening) -> Endpoint:
    from .pty import PtyPort  # tty and termios: POSIX only

    return PtyPort(opening.line, link=opening.values.get("link"), line_timing=opening.line_timing)


def _open_serial(opening: Opening) -> Endpoint:
    try:
        from .serial import SerialPort
    except ImportError as exc:
        raise C20SimError(f"--serial: pyserial cannot be loaded here ({exc}); use --tcp or --modbus-tcp") from None
    return SerialPort(
        opening.line,
        opening.values["serial"],
        parity=opening.parity,
        stopbits=opening.stopbits,
        line_timing=opening.line_timing,
    )


def _open_tcp(opening: Opening) -> Endpoint:
    from .tcp import RtuOverTcpServer, parse_host_port

    host, port = parse_host_port(opening.values["tcp"], "--tcp")
    return RtuOverTcpServer(
        opening.line, host, port, max_connections=opening.max_connections, timeout=opening.gateway_timeout
    )


def _open_modbus_tcp(opening: Opening) -> Endpoint:
    from .modbustcp import ModbusTcpServer
    from .tcp import parse_host_port

    host, port = parse_host_port(opening.values["modbus_tcp"], "--modbus-tcp")
    return ModbusTcpServer(
        opening.line, host, port, max_connections=opening.max_connections, timeout=opening.gateway_timeout
    )


def _introduce(attribute: str, key: str, endpoint: Endpoint, where: Callable[[str], str | None]) -> None:
    """Tell a TCP port where the other TCP protocol is served (``where(key)``, asked when a master errs)."""
    setattr(endpoint, attribute, functools.partial(where, key))


_ROWS: dict[str, Transport] = {}


def register(row: Transport) -> Callable[[], None]:
    """Add a transport (after the others, in the front ends' order); returns what removes it again."""
    taken = {o.flag for r in _ROWS.values() for o in r.options}
    if row.name in _ROWS or any(r.key == row.key for r in _ROWS.values()):
        raise ValueError(f"transport {row.name!r} (ready-file key {row.key!r}): the name or the key is taken")
    clash = sorted(taken & {o.flag for o in row.options})
    if clash:
        raise ValueError(f"transport {row.name!r}: option {clash[0]} belongs to another transport")
    _ROWS[row.name] = row

    def remove() -> None:
        if _ROWS.get(row.name) is row:
            del _ROWS[row.name]

    return remove


def rows() -> tuple[Transport, ...]:
    """The transports, in order: serve opens the asked-for ones in it."""
    return tuple(_ROWS.values())


def find(name: str) -> Transport | None:
    """The transport called ``name`` (``"modbus-tcp"``), or None."""
    return _ROWS.get(name)


register(
    Transport(
        name="pty",
        key="pty",
        options=(
            Option("--pty", "create a virtual serial port and print its path"),
            Option("--link", "a stable symlink to the pty, such as /tmp/ttyC20 (implies --pty)", "PATH"),
        ),
        opener=_open_pty,
        model="rtu",
        help="a virtual serial port (a pseudo-terminal) a master opens as a device",
        posix_only=NEEDS_POSIX,
        default=True,
        fixture=True,
    )
)
register(
    Transport(
        name="serial",
        key="serial",
        options=(Option("--serial", "a real serial port, such as /dev/ttyUSB0", "DEVICE"),),
        opener=_open_serial,
        model="rtu",
        help="a real serial port (a USB-RS485 adapter), at the drives' baud and --parity/--stopbits",
    )
)
register(
    Transport(
        name="tcp",
        key="tcp",
        options=(Option("--tcp", "raw RTU frames over TCP, as a serial device server", "HOST:PORT"),),
        opener=_open_tcp,
        model="rtu",
        help="RTU over TCP: raw RTU frames on a TCP port, as a serial device server carries them",
        network=True,
        default="127.0.0.1:5020",
        fixture="127.0.0.1:0",
        plant=PlantPort("rtu-tcp", 5020, 5020, "--rtu-port-base", "RTU over TCP"),
        introduce=functools.partial(_introduce, "modbus_tcp", "modbus_tcp"),
    )
)
register(
    Transport(
        name="modbus-tcp",
        key="modbus_tcp",
        options=(Option("--modbus-tcp", "Modbus TCP (MBAP), as an Ethernet gateway", "HOST:PORT"),),
        opener=_open_modbus_tcp,
        model="mbap",
        help="Modbus TCP: MBAP frames, as an Ethernet gateway in front of the RS485 line",
        network=True,
        default="127.0.0.1:1502",
        fixture="127.0.0.1:0",
        plant=PlantPort("modbus-tcp", 1502, 502, "--modbus-port-base", "Modbus TCP"),
        introduce=functools.partial(_introduce, "rtu_tcp", "tcp"),
    )
)
