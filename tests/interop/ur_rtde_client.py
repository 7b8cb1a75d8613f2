"""ur_rtde (PyPI `ur-rtde`) against `mmnormd sim robot`: RTDEReceiveInterface with its
default recipe and with an explicit list, and RTDEIOInterface. Prints the figures it checks and
exits non-zero on any failure. Usage: ur_rtde_client.py HOST (the simulator on port 30004)."""
import math
import sys
import time

import rtde_io
import rtde_receive

HOST = sys.argv[1]
START_POSE = [0.45, -0.20, 0.35, 0.0, math.pi, 0.0]  # UrSimConfig::default().start_pose


def timestamps(r, seconds):
    """The distinct controller timestamps seen while polling for `seconds`."""
    seen = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        t = r.getTimestamp()
        if not seen or t != seen[-1]:
            seen.append(t)
        time.sleep(0.0002)
    return seen


def check_stream(r, label):
    seen = timestamps(r, 1.0)
    steps = [round((b - a) * 1e3, 3) for a, b in zip(seen, seen[1:])]
    span = seen[-1] - seen[0]
    rate = round((len(seen) - 1) / span) if span > 0 else 0
    # Each step is a whole number of 2 ms periods; polling may miss some, never split one.
    whole = all(abs(s / 2.0 - round(s / 2.0)) < 1e-3 and s > 0 for s in steps)
    covered = span / 0.002 + 1
    pose = r.getActualTCPPose()
    pose_error = max(abs(a - b) for a, b in zip(pose, START_POSE))
    print(f"{label}: {len(seen)} timestamps over {span:.3f} s of controller time "
          f"({covered:.0f} periods of 2 ms), steps all whole periods: {whole}; "
          f"pose {['%.4f' % v for v in pose]} (off by {pose_error:.2e})")
    assert whole, steps[:20]
    assert 0.9 < span < 1.1, span
    assert pose_error < 1e-9, pose


def main():
    r = rtde_receive.RTDEReceiveInterface(HOST)
    assert r.isConnected()
    check_stream(r, "RTDEReceiveInterface, default recipe")
    print(f"  robot mode {r.getRobotMode()}, safety mode {r.getSafetyMode()}, "
          f"main voltage {r.getActualMainVoltage()} V, joint temperatures {r.getJointTemperatures()}, "
          f"payload {r.getPayload()} kg")
    r.disconnect()

    r = rtde_receive.RTDEReceiveInterface(HOST, 500.0, ["timestamp", "actual_TCP_pose", "actual_q"])
    assert r.isConnected()
    check_stream(r, "RTDEReceiveInterface, explicit list")
    r.disconnect()

    io = rtde_io.RTDEIOInterface(HOST)
    results = {
        "setStandardDigitalOut(0, True)": io.setStandardDigitalOut(0, True),
        "setToolDigitalOut(0, True)": io.setToolDigitalOut(0, True),
        "setSpeedSlider(0.5)": io.setSpeedSlider(0.5),
        "setAnalogOutputVoltage(0, 0.3)": io.setAnalogOutputVoltage(0, 0.3),
    }
    print("RTDEIOInterface: " + ", ".join(f"{k} -> {v}" for k, v in results.items()))
    assert all(results.values()), results
    io.disconnect()
    print("ur_rtde: all checks passed")


if __name__ == "__main__":
    main()
