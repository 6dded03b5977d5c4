"""Sensapex's own client (the `sensapex` package from PyPI, libum v1.504 inside)
against `cellinject emulate sensapex`: what the vendor's SDK does with our SMCP1
devices is the test of the emulator (docs/sensapex.md)."""

import os
import subprocess
import time

import pytest

try:
    from sensapex import UMP
except ImportError:  # pragma: no cover - depends on the environment
    UMP = None

ROOT_REQUIRED = os.environ.get("CELLINJECT_PYTEST") == "required"


def start_emulator(exe):
    """`cellinject emulate sensapex` on the first group 0..10 whose port (55555 +
    group) it can take on loopback (another test may hold one a moment); the process
    and its group."""
    for group in range(11):
        emu = subprocess.Popen(
            [exe, "emulate", "sensapex", "--group", str(group), "--devices",
             "ump:1,ump4:2,ums:21,umv:31", "--serve-for", "120"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        # Its first line says it listens; a taken port ends it with exit 2.
        line = emu.stdout.readline()
        if "SMCP1 devices on udp://127.0.0.1:%d" % (55555 + group) in line:
            return emu, group
        err = emu.stderr.read()
        emu.wait()
        assert "cannot listen" in err, line + err
    pytest.skip("UDP ports 55555-55565 are all taken on 127.0.0.1")


@pytest.fixture(scope="module")
def ump():
    if UMP is None:
        if ROOT_REQUIRED:
            pytest.fail("the `sensapex` package is not installed (pip install sensapex)")
        pytest.skip("the `sensapex` package is not installed (pip install sensapex)")
    exe = os.environ.get("CELLINJECT_BIN")
    if not exe:
        if ROOT_REQUIRED:
            pytest.fail("CELLINJECT_BIN is not set")
        pytest.skip("no cellinject binary (set CELLINJECT_BIN)")
    emu, group = start_emulator(exe)
    UMP._single = None
    u = UMP.get_ump(address=b"127.0.0.1", group=group)
    try:
        yield u
    finally:
        u.close()
        UMP._single = None
        emu.kill()
        emu.wait()


def test_the_client_finds_every_device(ump):
    assert sorted(ump.list_devices()) == [1, 2, 21, 31]
    assert ump.axis_count(1) == 3
    assert ump.axis_count(2) == 4
    assert ump.get_firmware_version(1)[:2] == (1, 504)


def test_goto_ends_within_a_nanometre_busy_only_while_moving(ump):
    dev = ump.get_device(1)
    start = dev.get_pos(timeout=-1)
    target = [start[0] + 250.0, start[1] - 120.5, start[2] + 33.25]
    t0 = time.monotonic()
    move = dev.goto_pos(target, speed=500)
    assert dev.is_busy()
    assert move.finished_event.wait(10)
    elapsed = time.monotonic() - t0
    assert not move.interrupted, move.interrupt_reason
    assert not dev.is_busy()
    end = dev.get_pos(timeout=-1)
    for a, b in zip(end, target):
        assert abs(a - b) <= 1e-3, (end, target)
    # 250 um at 500 um/s takes at least half a second.
    assert elapsed >= 0.5, elapsed


def test_a_four_axis_manipulator_moves_its_fourth_axis(ump):
    dev = ump.get_device(2)
    start = dev.get_pos(timeout=-1)
    assert len(start) == 4
    target = start[:3] + [start[3] + 40.0]
    move = dev.goto_pos(target, speed=1000)
    assert move.finished_event.wait(10)
    assert abs(dev.get_pos(timeout=-1)[3] - target[3]) <= 1e-3


def test_stop_halts_a_move_before_its_target(ump):
    dev = ump.get_device(21)  # a stage (ids 20-29)
    start = dev.get_pos(timeout=-1)
    target = [start[0] + 3000.0, start[1], start[2]]
    move = dev.goto_pos(target, speed=1000)
    time.sleep(0.4)
    assert dev.is_busy()
    dev.stop(reason="test")
    assert move.interrupted
    time.sleep(0.3)
    end = dev.get_pos(timeout=-1)
    assert start[0] + 100.0 < end[0] < target[0] - 1000.0, (start, end)
    assert not dev.is_busy()


def test_take_step_moves_by_the_step(ump):
    dev = ump.get_device(1)
    start = dev.get_pos(timeout=-1)
    dev.take_step([-12.5, 0.0, 4.0], speed=100)
    time.sleep(0.6)
    end = dev.get_pos(timeout=-1)
    assert abs(end[0] - (start[0] - 12.5)) <= 1e-3
    assert abs(end[2] - (start[2] + 4.0)) <= 1e-3
    assert end[1] == start[1]


def test_pressure_and_valve_round_trip_in_kpa(ump):
    pv = ump.get_device(31)
    pv.set_pressure(1, 12.5)
    assert pv.get_pressure(1) == pytest.approx(12.5, abs=1e-3)
    time.sleep(0.2)
    assert pv.measure_pressure(1) == pytest.approx(12.5, abs=0.01)
    pv.set_pressure(3, 0.75)
    assert pv.get_pressure(3) == pytest.approx(0.75, abs=1e-3)
    pv.set_valve(2, 1)
    assert pv.get_valve(2) == 1
    pv.set_valve(2, 0)
    assert pv.get_valve(2) == 0
