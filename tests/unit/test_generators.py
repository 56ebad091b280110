"""Generators: values as a function of model time, applied at ticks, the same however time is stepped."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import pytest

from c20sim.control import ops
from c20sim.core.generators import TICK, GeneratorError, Noise, Ramp, Sine, parse_generator
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.scenario.timeline import load_scenario, run

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"


def test_ramp_sine_and_noise_values() -> None:
    ramp = Ramp(start=1.0, start_value=48.0, to=30.0, over=2.0)
    assert [ramp.value(t) for t in (0.0, 1.0, 2.0, 3.0, 9.0)] == [48.0, 48.0, 39.0, 30.0, 30.0]
    assert (ramp.done(2.9), ramp.done(3.0)) == (False, True)
    sine = Sine(start=0.0, center=25.0, amplitude=5.0, period=1.0)
    assert [round(sine.value(t), 9) for t in (0.0, 0.25, 0.5, 0.75)] == [25.0, 30.0, 25.0, 20.0]
    noise = Noise(start=0.0, center=1.0, sigma=0.5, every=0.1, seed=3)
    samples = [noise.value(k * 0.1) for k in range(50)]
    assert samples == [Noise(0.0, 1.0, 0.5, 0.1, 3).value(k * 0.1) for k in range(50)]  # seeded: repeatable
    assert samples != [Noise(0.0, 1.0, 0.5, 0.1, 4).value(k * 0.1) for k in range(50)]
    assert noise.value(0.12) == noise.value(0.1) == noise.value(0.19)  # held between samples
    assert len(set(samples)) == 50 and 0.5 < sum(samples) / 50 < 1.5


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        (
            {},
            "supply_v: give one generator, such as { ramp = 30, over = 5 }, { sine = 2, period = 0.5 } or { noise = 0.5, seed = 1 }",
        ),
        ({"ramp": 30}, "supply_v: a ramp needs over = SECONDS, such as { ramp = 30, over = 5 }"),
        ({"ramp": 30, "over": -1}, "supply_v.over: -1 is outside 0-3.1536e+07"),
        ({"ramp": 3000, "over": 1}, "supply_v.ramp: 3000 is outside 0-2000"),
        ({"sine": 2, "period": 0.001}, "supply_v.period: 0.001 is outside 0.02-3.1536e+07"),
        ({"sine": 2}, "supply_v: a sine needs period = SECONDS, such as { sine = 2, period = 0.5 }"),
        ({"noise": 1, "seed": 1.5}, "supply_v.seed: expected a whole number, got 1.5"),
        ({"noise": 1, "over": 2}, "supply_v: unknown key 'over' for a noise; its keys: noise, seed, every, center"),
        ({"ramp": float("nan"), "over": 1}, "supply_v.ramp: expected a finite number, got nan"),
    ],
)
def test_bad_generators_say_what_is_wrong(spec: dict[str, object], message: str) -> None:
    with pytest.raises(GeneratorError) as caught:
        parse_generator("supply_v", spec, 0, 2000, 0.0, 48.0)
    assert str(caught.value) == message


def run_sim(steps: list[float]) -> list[dict[str, object]]:
    sim = Simulator(load_profile(), (1,), seed=1)
    ops.press_key(sim, 1, "forward")
    ops.set_run_channel(sim, 1, "keypad")
    ops.set_conditions(
        sim,
        1,
        {
            "supply_v": {"ramp": 40, "over": 3},
            "ambient_c": {"sine": 4, "period": 0.5},
            "load_torque_nm": {"noise": 0.1, "seed": 5, "center": 0.2},
        },
    )
    out = []
    for t in steps:
        sim.run_until(t)
        out.append(asdict(ops.telemetry(sim, 1)))
    return out


def test_the_same_model_times_give_the_same_values_however_time_is_stepped() -> None:
    marks = [1.0, 2.5, 4.0]
    coarse = run_sim(marks)
    fine_steps = sorted({round(k * 0.0037, 6) for k in range(1, 1081)} | set(marks))
    fine = {s["t"]: s for s in run_sim(fine_steps)}
    assert [fine[t] for t in marks] == coarse
    assert coarse[0]["supply_v"] == pytest.approx(48 - 8 / 3, abs=1e-9)
    assert coarse[2]["supply_v"] == 40.0


def test_a_generator_is_applied_tick_by_tick_as_the_drive_is_advanced() -> None:
    sim = Simulator(load_profile(), (1,))
    ops.set_conditions(sim, 1, {"supply_v": {"ramp": 30, "over": 1}})
    seen = []
    for k in range(1, 101):
        sim.run_until(k * TICK)
        seen.append(round(ops.conditions(sim, 1)["supply_v"], 9))  # type: ignore[arg-type]
    assert seen == [round(48 - 18 * k / 100, 9) for k in range(1, 101)]
    assert ops.generators(sim, 1) == {}  # a ramp that has arrived is done; its value stays
    assert ops.conditions(sim, 1)["supply_v"] == 30.0


def test_a_scenario_with_generators_gives_identical_results_run_twice() -> None:
    scenario = load_scenario(SCENARIOS / "supply_ripple.toml")
    first, second = (run(scenario, Simulator(load_profile(), (1,), seed=1)) for _ in range(2))
    assert first.ok, first.render()
    assert first.render() == second.render()
    assert [o.text for o in first.outcomes] == [o.text for o in second.outcomes]


def test_the_noise_seed_decides_the_run(tmp_path: Path) -> None:
    def telemetry(seed: int) -> list[tuple[float, float]]:
        path = tmp_path / f"noise{seed}.toml"
        path.write_text(
            '[[step]]\nat = 0\nwrite = { "2001H" = 1500, "2000H" = 1 }\n'
            f"set = {{ supply_v = {{ noise = 1.5, seed = {seed} }} }}\n"
        )
        sim = Simulator(load_profile(), (1,), seed=1)
        assert run(load_scenario(path), sim).ok
        out = []
        for k in range(1, 21):
            sim.run_until(k * 0.25)
            state = ops.telemetry(sim, 1)
            out.append((state.supply_v, state.bus_v))
        return out

    assert telemetry(11) == telemetry(11)
    assert telemetry(11) != telemetry(12)
