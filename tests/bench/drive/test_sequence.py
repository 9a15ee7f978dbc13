from __future__ import annotations

import numpy as np
import pytest

from bench.drive.cycles import load_trace
from bench.drive.generate import sample_times
from bench.drive.sequence import PREHEAT, TestSequence
from bench.drive.vehicle import VIRTUAL_VEHICLE, motor_speed_rpm

SEQ = TestSequence()


def test_sequence_lasts_7274_s_with_the_paper_phases():
    assert SEQ.duration_s == 7274.0
    assert [(p.name, p.start_s, p.end_s) for p in SEQ.phases] == [
        ("preheat1", 0.0, 1800.0), ("ftp75", 1800.0, 3674.0), ("preheat2", 3674.0, 5474.0), ("wltc3", 5474.0, 7274.0)]
    assert len(sample_times(SEQ.duration_s)) == 36371


def test_phase_boundaries_and_preheat_operating_point():
    assert list(SEQ.phase_at([0, 1799.8, 1800, 3673.8, 3674, 5473.8, 5474, 7274])) == [0, 0, 1, 1, 2, 2, 3, 3]
    torque, speed = SEQ.drive(np.array([0.0, 900.0, 1800.0, 3674.0 + 900.0, 5474.0]))
    assert list(torque) == [0.0, PREHEAT.torque_Nm, 0.0, PREHEAT.torque_Nm, 0.0]
    assert list(speed) == [0.0, PREHEAT.speed_rpm, 0.0, PREHEAT.speed_rpm, 0.0]


@pytest.mark.parametrize(("phase", "cycle"), [(1, "ftp75"), (3, "wltc3b")])
def test_motor_speed_follows_the_trace_and_covers_its_distance(phase, cycle):
    start = SEQ.phases[phase].start_s
    trace = load_trace(cycle)
    t = np.arange(0.0, trace.duration_s + 1e-9, 0.1)
    _, speed = SEQ.drive(start + t)
    expected = motor_speed_rpm(VIRTUAL_VEHICLE, np.interp(t, trace.time_s, trace.speed_kmh) / 3.6)
    np.testing.assert_allclose(speed, expected, atol=1e-9)
    wheel_mps = speed / VIRTUAL_VEHICLE.gear_ratio * 2 * np.pi / 60 * VIRTUAL_VEHICLE.wheel_radius_m
    assert np.trapezoid(wheel_mps, t) / 1000 == pytest.approx(trace.distance_km, abs=1e-3)


def test_torque_and_speed_stay_inside_the_motor_envelope():
    report = SEQ.envelope_report()
    assert report["min_envelope_margin_Nm"] > 0
    assert report["peak_speed_rpm"] < SEQ.motor.max_speed_rpm
    assert report["peak_speed_rpm"] == pytest.approx(motor_speed_rpm(VIRTUAL_VEHICLE, 131.3 / 3.6), rel=1e-9)
    assert report["peak_power_W"] <= SEQ.motor.rated_power_W
    assert report["min_torque_Nm"] < -100  # regenerative braking is used


def test_cycle_torque_is_traction_when_accelerating_and_regen_when_braking():
    start = SEQ.phases[1].start_s
    trace = load_trace("ftp75")
    accel = np.diff(trace.speed_kmh)
    up, down = int(np.argmax(accel)), int(np.argmin(accel))
    torque, _ = SEQ.drive(np.array([start + up + 0.5, start + down + 0.5, start]))
    assert torque[0] > 100 and torque[1] < -100 and torque[2] == 0.0
