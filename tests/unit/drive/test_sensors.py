"""The Hall sensors: codes from the rotor's angle, their edges, and the speed measured from them."""

from __future__ import annotations

import math

import pytest

from c20sim.drive.physics import HALL_SEQUENCE, RPM, STEP, TWO_PI, Segment
from c20sim.drive.sensors import HALL_TIMEOUT, Hall, HallFault, noise

POLE_PAIRS = 4


def turn(hall: Hall, rpm: float, steps: int, k0: int = 0) -> list[int]:
    """Step the sensors ``steps`` times at ``rpm`` from step ``k0``; the code after each step."""
    codes = []
    for k in range(k0, k0 + steps):
        hall.step(rpm, POLE_PAIRS, k * STEP)
        codes.append(hall.code())
    return codes


def test_a_healthy_sensor_steps_through_the_sequence_forward_and_back() -> None:
    hall = Hall()
    assert hall.code() == HALL_SEQUENCE[0]
    # 750 rpm at 4 pole pairs: 50 electrical revolutions a second, one sector every 1/300 s
    codes = turn(hall, 750.0, 20)
    changes = [c for i, c in enumerate(codes) if i == 0 or c != codes[i - 1]]
    assert changes == [1, 3, 2, 6, 4, 5, 1]
    assert hall.glitch is False
    back = turn(hall, -750.0, 7, 20)
    assert [c for i, c in enumerate(back) if i == 0 or c != back[i - 1]] == [5, 4, 6]
    assert hall.glitch is False


@pytest.mark.parametrize(("fault", "code"), [(HallFault.STUCK0, 0), (HallFault.STUCK7, 7)])
def test_a_stuck_sensor_reads_its_code_and_glitches_at_the_first_step(fault: HallFault, code: int) -> None:
    hall = Hall()
    hall.fault = fault
    assert hall.code() == code
    assert hall.now(0.5, 750.0, POLE_PAIRS) == code
    turn(hall, 0.0, 1)  # even standing still
    assert hall.glitch is True


def test_an_out_of_sequence_sensor_glitches_at_its_first_edge_not_before() -> None:
    hall = Hall()
    hall.fault = HallFault.SEQUENCE
    assert turn(hall, 750.0, 1) == [HALL_SEQUENCE[0]]  # 18 degrees electrical: the code has not changed yet
    assert hall.glitch is False
    assert turn(hall, 750.0, 1, 1) != [HALL_SEQUENCE[0]]  # 36 degrees, which this sensor reads as 72
    assert hall.glitch is True


def test_the_speed_is_measured_between_edges_and_reads_zero_once_they_stop() -> None:
    hall = Hall()
    turn(hall, 750.0, 20)
    t = 20 * STEP
    assert hall.edge_rpm == pytest.approx(750.0, rel=1e-9)
    assert hall.rpm(t, t, 750.0, POLE_PAIRS) == pytest.approx(750.0, rel=1e-9)
    edge = hall.edge_t
    assert edge is not None
    # standing still from here: the last edge's reading, bounded by the time since it, then 0
    per_rpm = 60.0 / (6 * POLE_PAIRS)
    assert hall.rpm(edge + 0.01, t, 0.0, POLE_PAIRS) == pytest.approx(per_rpm / 0.01)
    assert hall.rpm(edge + HALL_TIMEOUT + 1e-6, t, 0.0, POLE_PAIRS) == 0.0


def test_a_steady_segment_crosses_the_same_edges_as_its_steps() -> None:
    stepped, skipped = Hall(), Hall()
    turn(stepped, 750.0, 10)
    turn(skipped, 750.0, 10)
    skipped.mark_segment()
    rate = 750.0 * RPM * POLE_PAIRS * STEP
    seg = Segment(10, 25.0, 25.0, 0.0, 0.0, 0.0, 0.0, 0.0, skipped.theta, rate)
    turn(stepped, 750.0, 990, 10)
    skipped.skip(seg, 990, 10 * STEP, POLE_PAIRS)
    assert skipped.theta == pytest.approx(stepped.theta, abs=1e-9)
    assert skipped.code() == stepped.code() == skipped.before
    assert skipped.edge_t == pytest.approx(stepped.edge_t, abs=1e-9)
    assert skipped.edge_rpm == pytest.approx(750.0, rel=1e-9)


def test_3009h_follows_the_rotor_between_steps() -> None:
    hall = Hall()
    sector = (math.pi / 3.0) / (750.0 * RPM * POLE_PAIRS)  # seconds a sector takes
    assert [hall.now(sector * (i + 0.5), 750.0, POLE_PAIRS) for i in range(6)] == list(HALL_SEQUENCE)
    assert hall.theta == 0.0  # a look changes nothing
    assert hall.now(TWO_PI, 0.0, POLE_PAIRS) == HALL_SEQUENCE[0]


def test_the_read_noise_is_fixed_by_seed_and_step() -> None:
    values = [noise(7, k) for k in range(1000)]
    assert values == [noise(7, k) for k in range(1000)]
    assert all(-1.0 <= v < 1.0 for v in values)
    assert len(set(values)) == 1000
    assert noise(8, 0) != noise(7, 0)
    assert abs(sum(values) / len(values)) < 0.1
