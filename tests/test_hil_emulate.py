"""``qomni emulate`` as a separate process behind the socketcand hub, driven by an external master."""
from __future__ import annotations

import subprocess
import sys
import time

import numpy as np

from qomni.hil.master.client import VehicleClient
from qomni.hil.tools.hub import Hub, hub_bus_spec


QOMNI = [sys.executable, "-c", "from qomni.cli import main; main()"]


def _serve(spec, *args):
    return subprocess.Popen([*QOMNI, "emulate", "--bus", spec, *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _wait_ready(process, timeout=60.0):
    end = time.monotonic() + timeout
    lines = []
    while time.monotonic() < end:
        line = process.stdout.readline()
        if not line:
            break
        lines.append(line)
        if "emulating" in line:
            return lines
    process.kill()
    raise AssertionError("emulator did not start:\n" + "".join(lines))


def test_emulate_serves_an_external_master_and_reports_latency(tmp_path):
    faults = tmp_path / "faults.toml"
    faults.write_text("[latency]\nmean = 0.0001\n")
    with Hub() as hub:
        spec = hub_bus_spec(hub.port)
        process = _serve(spec, "--duration", "6", "--sync-timeout", "2", "--faults", str(faults))
        try:
            _wait_ready(process)
            from qomni.emulator.description import VehicleDescription

            drive = VehicleDescription.load().drive
            # the first cycle steps a freshly built plant in another process: on a loaded 2-core machine its
            # TPDOs have taken over 2 s
            with VehicleClient.from_drive(drive, spec, timeout=5.0, boot_timeout=5.0) as client:
                measurements = [client.exchange(np.full(4, 0.2)) for _ in range(100)]
            output = process.communicate(timeout=30)[0]
        finally:
            process.kill()
    assert measurements[-1].time == 99 * drive.cycle_time
    assert np.all(measurements[-1].motor_velocity > 0)                      # the wheels turned
    assert process.returncode == 0, output
    text = " ".join(output.split())
    assert "100 SYNCs; SYNC-to-last-TPDO latency median" in text and "late cycles" in text
    assert "delayed" in text


def test_emulate_refuses_bad_input(tmp_path):
    bad = subprocess.run([*QOMNI, "emulate", "--bus", "udp_multicast:x"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "not allowed" in bad.stdout
    plan = tmp_path / "f.toml"
    plan.write_text("[frame_loss]\nrate = 2.0\n")
    bad = subprocess.run([*QOMNI, "emulate", "--bus", "virtual",
                          "--faults", str(plan)], capture_output=True, text=True)
    assert bad.returncode == 2 and "rate must be in [0, 1]" in " ".join(bad.stdout.split())


def test_emulate_with_its_physics_in_a_process_of_its_own_and_busy_polling():
    """``qomni emulate --plant-process --busy-poll`` behind a busy-polling hub, lock-step: the same
    measurements, bit for bit, as the embedded vehicle of the same seed driven with the same torques."""
    from qomni.emulator.description import VehicleDescription
    from qomni.embedded import embedded_vehicle

    description = VehicleDescription.load()
    torques = [np.array([0.4, -0.3, 0.6, 0.2]) * np.sin(k / 7) for k in range(100)]
    with embedded_vehicle(description, seed=0) as client:
        expected = [client.exchange(u) for u in torques]
    with Hub(busy_poll=0.0005) as hub:
        spec = hub_bus_spec(hub.port)
        process = _serve(spec, "--duration", "8", "--sync-timeout", "2", "--plant-process",
                         "--busy-poll", "0.0005")
        try:
            _wait_ready(process)
            with VehicleClient.from_drive(description.drive, spec, timeout=2.0, boot_timeout=5.0) as client:
                got = [client.exchange(u) for u in torques]
            output = process.communicate(timeout=30)[0]
        finally:
            process.kill()
    assert process.returncode == 0, output
    for a, b in zip(got, expected):
        for field in ("motor_position", "motor_velocity", "motor_torque", "alpha"):
            assert getattr(a, field).tobytes() == getattr(b, field).tobytes(), field


def test_busy_polling_is_refused_where_it_means_nothing():
    bad = subprocess.run([*QOMNI, "emulate", "--bus", "virtual", "--busy-poll", "0.001"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "socketcand" in " ".join(bad.stdout.split())
    bad = subprocess.run([*QOMNI, "hub", "--port", "0", "--busy-poll", "-1"], capture_output=True, text=True)
    assert bad.returncode == 2 and "--busy-poll" in bad.stdout
