"""A plant of drives on Kubernetes: ``c20sim plant`` writes the manifests, ``c20sim plant-check`` polls them.

A plant is N buses, each an RS-485 line behind a gateway: one Deployment per
bus whose pod serves that bus's drives on every network transport with a
plant port (c20sim.transport.rows: RTU over TCP on 5020 and Modbus TCP on
1502 as shipped), a Service per bus (the cluster's name for it), and one
ConfigMap with the profile and the drives list that every bus reads. The same file runs on a
cluster (``kubectl apply -f``) and on one machine (``podman kube play``, which
plays the Deployments with their hostPorts and ignores the Services).

The manifests are written by hand-rolled YAML (block style, double-quoted
strings where a plain scalar could be misread), so the package needs no YAML
library; the tests read the output back with an independent parser.
"""

from __future__ import annotations

import argparse
import itertools
import os
import re
import sys
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from . import __version__
from .core.simulator import parse_addresses
from .drive.files import FileReadError, read_text
from .drive.profile import DEFAULT_PROFILE, Profile, load_profile
from .transport.probe import NoAnswer, Prober
from .transport.rows import PlantPort, rows
from .transport.tcp import parse_host_port
from .wire.errors import C20SimError
from .wire.protocol import ExceptionResponse
from .wire.registers import STATUS_WORDS, Reg

__all__ = ["PlantSpec", "add_plant_commands", "check_bus", "plant_manifests", "to_yaml"]

#: Each pod's read-only GET /metrics listener (serve --metrics), for Prometheus' scrape annotations.
METRICS_PORT = 9120
#: The metrics listener as a published port (not a transport: no Service port, no plant-check).
METRICS = PlantPort("metrics", METRICS_PORT, METRICS_PORT, "--metrics-port-base", "GET /metrics for Prometheus")
#: the environment variable that carries the drives list (from the ConfigMap) to serve and to the probe
DRIVES_ENV = "C20SIM_DRIVES"
#: the image's user (deploy/Containerfile)
IMAGE_UID = 10020
MAX_BUSES = 1000
_NAME = re.compile(r"[a-z]([-a-z0-9]*[a-z0-9])?")


@dataclass(frozen=True)
class PlantSpec:
    """What ``c20sim plant`` was asked for, checked."""

    buses: int
    drives: str
    profile_name: str
    profile_text: str
    image: str
    name: str = "c20sim"
    #: bus 0's host port by its option (``--rtu-port-base``), where not the port inside the container
    port_bases: Mapping[str, int] = field(default_factory=dict)

    def base(self, port: PlantPort) -> int:
        """Bus 0's host port of ``port``: bus i's is BASE+i."""
        return self.port_bases.get(port.base_option, port.container_port)

    def bus_name(self, bus: int) -> str:
        return f"{self.name}-bus-{bus}"

    @property
    def config_name(self) -> str:
        return f"{self.name}-plant"


def wire_ports() -> list[tuple[str, PlantPort]]:
    """Each transport a plant's pod serves (its option, its port), in the rows' order."""
    return [(row.options[0].flag, row.plant) for row in rows() if row.plant is not None]


def published() -> list[PlantPort]:
    """Every port a pod publishes: the transports', then the metrics listener."""
    return [port for _, port in wire_ports()] + [METRICS]


def probe_port() -> tuple[int, bool]:
    """The port the readiness probe and plant-check poll: the first plant transport carrying RTU frames (else the
    first one), and whether it speaks Modbus TCP."""
    ports = [(row.plant, row.model) for row in rows() if row.plant is not None]
    port, model = next(((p, m) for p, m in ports if m == "rtu"), ports[0])
    return port.container_port, model == "mbap"


def check_spec(spec: PlantSpec) -> None:
    """Raise C20SimError naming the option and its allowed range."""
    if not 1 <= spec.buses <= MAX_BUSES:
        raise C20SimError(f"--buses {spec.buses}: give 1-{MAX_BUSES}")
    parse_addresses(spec.drives)
    # every derived name (NAME-bus-N, NAME-plant) must stay a DNS label: at most 63 characters
    longest = max(63 - len(spec.bus_name(spec.buses - 1)) + len(spec.name), 0)
    if not _NAME.fullmatch(spec.name) or len(spec.name) > longest:
        raise C20SimError(
            f"--name {spec.name!r}: give lower-case letters, digits and '-', starting with a letter, "
            f"at most {longest} characters"
        )
    bases = {port.base_option: spec.base(port) for port in published()}
    for option, base in bases.items():
        if not 1 <= base <= 65536 - spec.buses:
            raise C20SimError(f"{option} {base}: give 1-{65536 - spec.buses} (bus i is published at BASE+i)")
    for (one, a), (other, b) in itertools.combinations(bases.items(), 2):
        if set(range(a, a + spec.buses)) & set(range(b, b + spec.buses)):
            raise C20SimError(f"{one} {a} and {other} {b}: the host ports of {spec.buses} buses overlap; move one base")
    if not spec.image or any(c.isspace() for c in spec.image):
        raise C20SimError(f"--image {spec.image!r}: give an image name such as localhost/c20sim:{__version__}")


def plant_manifests(spec: PlantSpec) -> list[dict[str, Any]]:
    """The ConfigMap, then a Deployment and a Service per bus."""
    check_spec(spec)
    part_of = {"app.kubernetes.io/name": "c20sim", "app.kubernetes.io/part-of": spec.name}
    docs: list[dict[str, Any]] = [
        {
            "apiVersion": "v1",
            "kind": "ConfigMap",
            "metadata": {"name": spec.config_name, "labels": part_of},
            "data": {"drives": spec.drives, "profile.toml": spec.profile_text},
        }
    ]
    for bus in range(spec.buses):
        labels = {**part_of, "c20sim/bus": str(bus)}
        docs.append(_deployment(spec, bus, labels))
        docs.append(
            {
                "apiVersion": "v1",
                "kind": "Service",
                "metadata": {"name": spec.bus_name(bus), "labels": labels},
                "spec": {
                    "selector": labels,
                    "ports": [
                        {"name": port.name, "port": port.service_port, "targetPort": port.name, "protocol": "TCP"}
                        for _, port in wire_ports()
                    ],
                },
            }
        )
    return docs


def _probe_command() -> list[str]:
    port, modbus_tcp = probe_port()
    return ["c20sim", "plant-check", "--quiet", *(["--modbus-tcp"] if modbus_tcp else []), f"127.0.0.1:{port}"]


def _deployment(spec: PlantSpec, bus: int, labels: Mapping[str, str]) -> dict[str, Any]:
    container = {
        "name": "c20sim",
        "image": spec.image,
        "imagePullPolicy": "IfNotPresent",
        "args": [
            *(word for option, port in wire_ports() for word in (option, f"0.0.0.0:{port.container_port}")),
            "--profile",
            "/etc/c20sim/profile.toml",
            "--metrics",
            f"0.0.0.0:{METRICS_PORT}",
        ],
        # serve and the readiness probe both take the drives from $C20SIM_DRIVES, so the ConfigMap is
        # their one source (podman kube play does not expand $(VAR) in args, a cluster would)
        "env": [
            {
                "name": DRIVES_ENV,
                "valueFrom": {"configMapKeyRef": {"name": spec.config_name, "key": "drives"}},
            }
        ],
        "ports": [
            {
                "name": port.name,
                "containerPort": port.container_port,
                "hostPort": spec.base(port) + bus,
                "protocol": "TCP",
            }
            for port in published()
        ],
        # ready when every drive of the bus answers a Modbus read (the drives come from $C20SIM_DRIVES)
        "readinessProbe": {
            "exec": {"command": _probe_command()},
            "initialDelaySeconds": 1,
            "periodSeconds": 5,
            "timeoutSeconds": 5,
        },
        "volumeMounts": [{"name": "config", "mountPath": "/etc/c20sim", "readOnly": True}],
    }
    return {
        "apiVersion": "apps/v1",
        "kind": "Deployment",
        "metadata": {"name": spec.bus_name(bus), "labels": labels},
        "spec": {
            "replicas": 1,
            "selector": {"matchLabels": labels},
            "template": {
                "metadata": {
                    "labels": labels,
                    # the annotations Prometheus' usual kubernetes_sd relabelling looks for
                    "annotations": {
                        "prometheus.io/scrape": "true",
                        "prometheus.io/port": str(METRICS_PORT),
                        "prometheus.io/path": "/metrics",
                    },
                },
                "spec": {
                    "securityContext": {"runAsNonRoot": True, "runAsUser": IMAGE_UID, "runAsGroup": IMAGE_UID},
                    "containers": [container],
                    "volumes": [{"name": "config", "configMap": {"name": spec.config_name}}],
                },
            },
        },
    }


# --- YAML out: just what the manifests use.

_PLAIN = re.compile(r"[A-Za-z_/][A-Za-z0-9_./-]*")
_RESERVED = {"y", "n", "yes", "no", "true", "false", "on", "off", "null"}


def _scalar(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if not isinstance(value, str):
        raise TypeError(f"no YAML for {type(value).__name__}")
    if _PLAIN.fullmatch(value) and value.lower() not in _RESERVED:
        return value
    return _quoted(value)


_ESCAPES = {"\\": "\\\\", '"': '\\"', "\n": "\\n", "\t": "\\t", "\r": "\\r"}


def _printable(char: str) -> bool:
    """YAML's printable set, less the characters it reads as line breaks (NEL, LS, PS) and the BOM."""
    code = ord(char)
    return (
        0x20 <= code <= 0x7E
        or 0xA0 <= code <= 0xD7FF
        or (0xE000 <= code <= 0xFFFD and code != 0xFEFF)
        or code >= 0x10000
    ) and code not in (0x2028, 0x2029)


def _quoted(value: str) -> str:
    """A YAML double-quoted scalar, with every character a reader could mistake escaped."""
    out = []
    for char in value:
        if char in _ESCAPES:
            out.append(_ESCAPES[char])
        elif _printable(char):
            out.append(char)
        elif ord(char) <= 0xFF:
            out.append(f"\\x{ord(char):02x}")
        elif ord(char) <= 0xFFFF:
            out.append(f"\\u{ord(char):04x}")
        else:
            out.append(f"\\U{ord(char):08x}")
    return '"' + "".join(out) + '"'


def _block(text: str, indent: str) -> list[str] | None:
    """A literal block scalar, or None where one cannot hold the text exactly."""
    if not text.endswith("\n") or text.endswith("\n\n"):
        return None
    lines = text[:-1].split("\n")
    if not any(lines) or any(line != line.rstrip(" ") or not all(map(_printable, line)) for line in lines):
        return None  # a block of blank lines only reads back as ""; trailing spaces and escapes need quotes
    return ["|2"] + [f"{indent}{line}" if line else "" for line in lines]


def _emit(value: object, indent: str, out: list[str], prefix: str) -> None:
    """Append ``prefix`` followed by ``value`` (``prefix`` ends in 'key:' or '- ')."""
    if isinstance(value, Mapping):
        if not value:
            out.append(f"{prefix} {{}}" if prefix.endswith(":") else f"{prefix}{{}}")
            return
        first = True
        for key, item in value.items():
            if prefix.endswith("- ") and first:
                _emit(item, indent + "  ", out, f"{prefix}{_scalar(key)}:")
                first = False
            else:
                if first and prefix:
                    out.append(prefix)
                first = False
                _emit(item, indent + "  ", out, f"{indent}{_scalar(key)}:")
        return
    if isinstance(value, list | tuple):
        if not value:
            out.append(f"{prefix} []")
            return
        if prefix:
            out.append(prefix)
        for item in value:
            _emit(item, indent + "  ", out, f"{indent}- ")
        return
    sep = "" if prefix.endswith("- ") or not prefix else " "
    if isinstance(value, str) and "\n" in value:
        block = _block(value, indent)
        if block is not None:
            out.append(f"{prefix}{sep}{block[0]}")
            out.extend(block[1:])
            return
    out.append(f"{prefix}{sep}{_scalar(value)}")


def to_yaml(docs: Iterable[Mapping[str, Any]], header: Sequence[str] = ()) -> str:
    """Documents as one multi-document YAML text, with ``header`` as comment lines."""
    out = [f"# {line}" if line else "#" for line in header]
    for doc in docs:
        out.append("---")
        _emit(doc, "", out, "")
    return "\n".join(out) + "\n"


# --- c20sim plant


def cmd_plant(args: argparse.Namespace) -> int:
    profile: Profile = load_profile(args.profile)
    try:
        profile_text = read_text(profile.path, "profile")
    except FileReadError as exc:
        raise C20SimError(f"--profile {args.profile}: cannot read {exc}") from None
    spec = PlantSpec(
        buses=args.buses,
        drives=args.drives,
        profile_name=profile.name,
        profile_text=profile_text,
        image=args.image,
        name=args.name,
        port_bases={port.base_option: getattr(args, _dest(port.base_option)) for port in published()},
    )
    text = to_yaml(plant_manifests(spec), plant_header(spec, args.profile))
    if args.output and args.output != "-":
        try:
            with open(args.output, "w", encoding="utf-8") as f:
                f.write(text)
        except OSError as exc:
            raise C20SimError(f"--output {args.output}: cannot write: {exc.strerror}") from None
    else:
        sys.stdout.write(text)
    return 0


def plant_header(spec: PlantSpec, profile: str) -> list[str]:
    """The comment lines at the top of the manifests: what the plant is, and how to run, check and end it."""
    last = spec.buses - 1
    services = ", ".join(f"{port.title} :{port.service_port}" for _, port in wire_ports())
    hosts = " and ".join(f"{port.title} {spec.base(port)}+i" for _, port in wire_ports())
    port, modbus_tcp = probe_port()
    check = next(p for _, p in wire_ports() if p.container_port == port)
    base = spec.base(check)
    return [
        f"A c20sim plant: {spec.buses} bus(es), drives {spec.drives} on each, profile {spec.profile_name}.",
        f"Generated by c20sim {__version__}: {command_line(spec, profile)}",
        "",
        f"On a cluster:      kubectl apply -f THIS_FILE  (Services {spec.name}-bus-N: {services})",
        "On one machine:    podman kube play THIS_FILE  (podman ignores the Services; the hostPorts publish",
        f"                   bus i at {hosts})",
        f"Check every drive: c20sim plant-check --drives {spec.drives} "
        + ("--modbus-tcp " if modbus_tcp else "")
        + (
            " ".join(f"127.0.0.1:{base + bus}" for bus in range(spec.buses))
            if spec.buses <= 4
            else f"127.0.0.1:{base} ... 127.0.0.1:{base + last}"
        ),
        "Tear down:         podman kube down THIS_FILE  (or kubectl delete -f THIS_FILE)",
        "The control API is not served: it has no token yet, so keep it loopback-only.",
    ]


def _dest(option: str) -> str:
    return option.removeprefix("--").replace("-", "_")


def command_line(spec: PlantSpec, profile: str) -> str:
    """The ``c20sim plant`` command that writes this plant again."""
    words = ["c20sim", "plant", "--buses", str(spec.buses), "--drives", spec.drives, "--profile", profile]
    words += ["--image", spec.image]
    if spec.name != "c20sim":
        words += ["--name", spec.name]
    for port in published():
        if spec.base(port) != port.container_port:
            words += [port.base_option, str(spec.base(port))]
    return " ".join(words)


# --- c20sim plant-check


def drive_addresses(given: str | None) -> list[int]:
    """``--drives`` when given, else ``$C20SIM_DRIVES`` when set, else drive 1; an error names its source."""
    if given is not None:
        return parse_addresses(given)
    from_env = os.environ.get(DRIVES_ENV)
    if not from_env:
        return [1]
    try:
        return parse_addresses(from_env)
    except C20SimError as exc:
        raise C20SimError(f"${DRIVES_ENV}: {exc}") from None


@dataclass(frozen=True)
class DriveRow:
    bus: str
    drive: int
    ok: bool
    status: str
    speed: int | None


def check_bus(
    host: str, port: int, drives: Sequence[int], profile: Profile, *, modbus_tcp: bool = False, timeout: float = 0.5
) -> list[DriveRow]:
    """Poll every drive of one bus once: drive ID, status word 1, fault code, motor speed."""
    label = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    rows = []
    with Prober(host, port, modbus_tcp=modbus_tcp, timeout=timeout) as prober:
        for drive in drives:
            try:
                values = [
                    prober.read(drive, reg) for reg in (Reg.DRIVE_ID, Reg.STATUS1, Reg.FAULT_CODE, Reg.MOTOR_SPEED)
                ]
            except NoAnswer as exc:
                rows.append(DriveRow(label, drive, False, f"no answer: {exc}", None))
                continue
            refused = [v for v in values if isinstance(v, ExceptionResponse)]
            if refused:
                rows.append(DriveRow(label, drive, False, f"exception 0x{refused[0].code:02X}", None))
                continue
            _drive_id, status1, fault, speed = (int(v) for v in values if not isinstance(v, ExceptionResponse))
            rows.append(DriveRow(label, drive, True, _status(status1, fault, profile), speed))
    return rows


def _status(status1: int, fault: int, profile: Profile) -> str:
    if fault:
        spec = profile.faults.get(fault)
        return f"fault 0x{fault:02X} {spec.name}" if spec is not None else f"fault 0x{fault:02X}"
    return STATUS_WORDS.get(status1, f"status word 1 = {status1}")


def render_table(rows: Sequence[DriveRow]) -> str:
    bus_width = max([3, *(len(r.bus) for r in rows)])
    lines = [f"{'bus':<{bus_width}}  {'drive':>5}  {'speed':>5}  status"]
    for r in rows:
        speed = f"{r.speed:>5}" if r.speed is not None else f"{'-':>5}"
        lines.append(f"{r.bus:<{bus_width}}  {r.drive:>5}  {speed}  {r.status}")
    answered = sum(r.ok for r in rows)
    buses = len({r.bus for r in rows})
    lines.append(f"{answered} of {len(rows)} drives on {buses} bus(es) answered")
    return "\n".join(lines) + "\n"


def cmd_plant_check(args: argparse.Namespace) -> int:
    drives = drive_addresses(args.drives)
    if not 0.01 <= args.timeout <= 60:
        raise C20SimError(f"--timeout {args.timeout:g}: give 0.01-60 seconds")
    buses = [parse_host_port(host, "plant-check") for host in args.hosts]
    profile = load_profile(args.profile)
    with ThreadPoolExecutor(max_workers=min(16, len(buses))) as pool:
        results = pool.map(
            lambda hp: check_bus(hp[0], hp[1], drives, profile, modbus_tcp=args.modbus_tcp, timeout=args.timeout),
            buses,
        )
        rows = [row for bus_rows in results for row in bus_rows]
    if not args.quiet:
        sys.stdout.write(render_table(rows))
    return 0 if all(r.ok for r in rows) else 1


def add_plant_commands(sub: Any) -> None:
    """Register ``plant`` and ``plant-check`` on the ``c20sim`` subcommand parser."""
    plant = sub.add_parser(
        "plant",
        help="write Kubernetes manifests for a plant of N buses (kubectl apply, or podman kube play)",
        description="Kubernetes manifests for a plant: a ConfigMap (profile, drives), and a Deployment and a "
        "Service per bus, each pod serving "
        + " and ".join(f"{port.title} ({port.container_port})" for _, port in wire_ports())
        + ".",
    )
    plant.add_argument("--buses", type=int, required=True, help=f"number of buses, 1-{MAX_BUSES}")
    plant.add_argument("--drives", default="1", metavar="LIST", help="drive addresses on each bus, such as 1-32")
    plant.add_argument(
        "--profile", default=DEFAULT_PROFILE, help="profile name or TOML path, copied into the ConfigMap"
    )
    plant.add_argument("--image", default=f"localhost/c20sim:{__version__}", help="the image (deploy/build-image)")
    plant.add_argument("--name", default="c20sim", help="prefix of every object's name (default c20sim)")
    for port in published():
        plant.add_argument(
            port.base_option,
            type=int,
            default=port.container_port,
            help=f"hostPort of bus 0's {port.title} (default {port.container_port})",
        )
    plant.add_argument("-o", "--output", metavar="FILE", help="write here instead of standard output")
    plant.set_defaults(func=cmd_plant)

    check = sub.add_parser(
        "plant-check",
        help="poll every drive of every bus once and print a table (bus, drive, speed, status)",
        description="Polls each drive once (2103H drive ID, 2100H status, 2102H fault, 3006H speed). "
        "Exit 0 when every drive answered, 1 when one did not.",
    )
    check.add_argument("hosts", nargs="+", metavar="HOST:PORT", help="each bus's RTU over TCP endpoint")
    check.add_argument(
        "--drives", metavar="LIST", help=f"drive addresses on each bus (default ${DRIVES_ENV}, or 1 without it)"
    )
    check.add_argument("--modbus-tcp", action="store_true", help="the endpoints speak Modbus TCP, not RTU over TCP")
    check.add_argument("--timeout", type=float, default=0.5, help="seconds to wait for each answer (default 0.5)")
    check.add_argument("--profile", default=DEFAULT_PROFILE, help="profile whose fault names to show")
    check.add_argument("-q", "--quiet", action="store_true", help="print nothing; the exit code says (a probe)")
    check.set_defaults(func=cmd_plant_check)
