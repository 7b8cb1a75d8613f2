#!/usr/bin/env bash
# Interop tests against third-party clients, installed from PyPI into a throwaway venv:
# ur_rtde's RTDEReceiveInterface and RTDEIOInterface against `mmnormd sim robot` (on its own
# loopback address, 127.0.0.2, since ur_rtde's port is fixed at 30004), the Python `mcap`
# package's indexed and stream readers over a recorded scan, and numpy over a capture directory
# and `capture decode`'s output. Skips with a message only when PyPI cannot be reached, or when
# the machine has no python3 able to make a venv to install into.
# Usage: tools/interop.sh [path/to/mmnormd]   (default: target/release/mmnormd)
set -euo pipefail
cd "$(dirname "$0")/.."
MMNORMD=$(realpath "${1:-target/release/mmnormd}")
PINS=(ur-rtde==1.6.5 mcap==1.6.0 numpy==2.4.6)
HERE=$(pwd)
WORK=$(mktemp -d)
SIM_PID=""
cleanup() {
    if [ -n "$SIM_PID" ]; then kill "$SIM_PID" 2>/dev/null || true; wait "$SIM_PID" 2>/dev/null || true; fi
    rm -rf "$WORK"
}
trap cleanup EXIT

if ! command -v python3 > /dev/null; then
    echo "interop: SKIPPED: no python3 on this machine, so the PyPI clients cannot be installed"
    exit 0
fi
if ! python3 -c "import urllib.request; urllib.request.urlopen('https://pypi.org/simple/ur-rtde/', timeout=15)" 2>/dev/null; then
    echo "interop: SKIPPED: PyPI (https://pypi.org) cannot be reached from this machine"
    exit 0
fi
if ! python3 -m venv "$WORK/venv" > "$WORK/venv.log" 2>&1; then
    cat "$WORK/venv.log"
    echo "interop: SKIPPED: python3 cannot create a virtual environment here (Debian: python3-venv)"
    exit 0
fi
"$WORK/venv/bin/pip" install --quiet --disable-pip-version-check "${PINS[@]}"
PY="$WORK/venv/bin/python"
echo "interop: ${PINS[*]} installed"

# 1. ur_rtde against the UR5e simulator.
"$MMNORMD" -q sim robot --address 127.0.0.2 > "$WORK/sim.log" 2>&1 &
SIM_PID=$!
for _ in $(seq 50); do
    grep -q "UR5e simulator" "$WORK/sim.log" && break
    sleep 0.1
done
timeout 120 "$PY" tests/interop/ur_rtde_client.py 127.0.0.2
kill "$SIM_PID"; wait "$SIM_PID" 2>/dev/null || true; SIM_PID=""

# 2. A scan of the simulated lab, recorded to MCAP, read by the mcap package and numpy.
mkdir -p "$WORK/lab/config" "$WORK/lab/tools/scenes" "$WORK/lab/firmware_cfg"
cp config/sim.toml "$WORK/lab/config/"
cp tools/scenes/lab_sphere.toml "$WORK/lab/tools/scenes/"
cp firmware_cfg/iwr1443_demo.cfg "$WORK/lab/firmware_cfg/"
sed -i -e 's/^width_m = .*/width_m = 0.04/' -e 's/^height_m = .*/height_m = 0.02/' "$WORK/lab/config/sim.toml"
(cd "$WORK" && timeout 600 "$MMNORMD" -q demo --config lab/config/sim.toml --out "$WORK/scans" --name interop > "$WORK/demo.log" 2>&1) || { cat "$WORK/demo.log"; exit 1; }
MCAP=$(find "$WORK/scans" -name '*.mcap' | head -n 1)
CAPTURE=$(dirname "$(find "$WORK/scans" -name capture.json | head -n 1)")
timeout 120 "$PY" tests/interop/mcap_read.py "$MCAP"
timeout 120 "$PY" tests/interop/numpy_read.py capture "$CAPTURE"

# 3. An adc_data.bin written by numpy in TI's 4-lane layout, decoded by mmnormd, read back.
timeout 120 "$PY" tests/interop/numpy_read.py write "$WORK/adc_data.bin" 3 1 4 256
"$MMNORMD" -q capture decode "$WORK/adc_data.bin" --config config/sim.toml --out "$WORK/decoded"
timeout 120 "$PY" tests/interop/numpy_read.py decoded "$WORK/decoded" "$WORK/adc_data.bin" 3 1 4 256
cd "$HERE"
echo "interop: all third-party clients passed"
