"""``GET /metrics``: the Prometheus text format, read back by the Prometheus client's own parser, with the
counts a pymodbus master made on the wire."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families
from pymodbus.client import ModbusTcpClient
from pymodbus.framer import FramerType

from tests.conftest import wait_for_ready_file
from tests.tui.conftest import serving


def scrape(url: str) -> tuple[str, dict[tuple[str, tuple[tuple[str, str], ...]], float]]:
    with urllib.request.urlopen(f"{url}/metrics", timeout=10) as response:
        kind = response.headers["Content-Type"]
        text = response.read().decode()
    samples = {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
    }
    return kind, samples


def test_metrics_count_what_a_master_did() -> None:
    with serving((1, 2)) as served:
        client = ModbusTcpClient("127.0.0.1", port=served.port, framer=FramerType.RTU, timeout=5, retries=0)
        assert client.connect()
        try:
            for _ in range(5):
                assert not client.read_holding_registers(0x2100, count=1, device_id=1).isError()
            assert client.read_holding_registers(0x0032, count=1, device_id=1).exception_code == 0x02
            assert not client.read_holding_registers(0x2100, count=1, device_id=2).isError()
        finally:
            client.close()
        kind, samples = scrape(served.url)
        bus_v = served.call(lambda: served.sim.drive(1).telemetry().bus_v)
    assert kind.startswith("text/plain; version=0.0.4")
    one, two = (("drive", "1"),), (("drive", "2"),)
    assert samples[("c20sim_requests_total", one)] == 6
    assert samples[("c20sim_replies_total", one)] == 5  # the exception reply is counted apart
    assert samples[("c20sim_requests_total", two)] == 1
    assert samples[("c20sim_exceptions_total", (("code", "0x02"), ("drive", "1")))] == 1
    assert ("c20sim_exceptions_total", (("code", "0x02"), ("drive", "2"))) not in samples
    assert samples[("c20sim_crc_errors_total", one)] == 0
    assert samples[("c20sim_state", (("drive", "1"), ("state", "stopped")))] == 1
    assert samples[("c20sim_state", (("drive", "1"), ("state", "forward")))] == 0
    assert samples[("c20sim_bus_voltage_volts", one)] == bus_v  # the model's own figure, at the scrape's time
    assert samples[("c20sim_fault_code", one)] == 0
    # every reply is in the latency histogram, once, in a bucket at or below +Inf
    assert samples[("c20sim_reply_latency_seconds_count", ())] == 7
    assert samples[("c20sim_reply_latency_seconds_bucket", (("le", "+Inf"),))] == 7
    assert 0 < samples[("c20sim_reply_latency_seconds_sum", ())] < 7 * 1.0
    assert samples[("c20sim_line_waiting", ())] == 0


def test_metrics_speaks_openmetrics_when_asked() -> None:
    with serving() as served:
        request = urllib.request.Request(
            f"{served.url}/metrics", headers={"Accept": "application/openmetrics-text;version=1.0.0"}
        )
        with urllib.request.urlopen(request, timeout=10) as response:
            kind, text = response.headers["Content-Type"], response.read().decode()
    assert kind.startswith("application/openmetrics-text; version=1.0.0")
    assert text.endswith("# EOF\n")


def test_metrics_is_described_and_listed() -> None:
    from c20sim.control.openapi import document
    from c20sim.control.routes import table

    assert "get" in document(table())["paths"]["/metrics"]
    assert "GET /metrics" in table().listing()


def test_serve_metrics_listener_answers_metrics_alone(tmp_path: Path) -> None:
    """``serve --metrics`` (what each plant pod runs): GET /metrics without a token, and nothing else."""
    ready = tmp_path / "ready.json"
    command = [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--metrics", "127.0.0.1:0"]
    proc = subprocess.Popen([*command, "--ready-file", str(ready)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        info = wait_for_ready_file(ready, proc)
        url = info["metrics"]
        assert url.startswith("http://127.0.0.1:") and url.endswith("/metrics")
        with urllib.request.urlopen(url, timeout=10) as response:
            families = {f.name for f in text_string_to_metric_families(response.read().decode())}
        assert {"c20sim_requests", "c20sim_state", "c20sim_reply_latency_seconds"} <= families
        # Prometheus reaches a pod through a Service: its DNS name in Host is answered (the listener is read-only)
        by_name = urllib.request.Request(url, headers={"Host": "c20sim-bus-1.plant.svc.cluster.local:9120"})
        with urllib.request.urlopen(by_name, timeout=10) as response:
            assert response.status == 200
            assert "c20sim_requests_total" in response.read().decode()
        for other in ("/", "/drives/1", "/telemetry"):
            with pytest.raises(urllib.error.HTTPError) as refused:
                urllib.request.urlopen(url.removesuffix("/metrics") + other, timeout=10)
            assert refused.value.code == 404
            said = json.loads(refused.value.read())["error"]
            assert said == f"GET {other}: Not Found; this listener serves GET /metrics only"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_the_control_api_still_refuses_a_foreign_host_name() -> None:
    """The Host check stays on the control API (it changes state): a DNS-rebinding name is refused 403."""
    with serving() as served:
        request = urllib.request.Request(f"{served.url}/metrics", headers={"Host": "attacker.example:8020"})
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(request, timeout=10)
    assert refused.value.code == 403
