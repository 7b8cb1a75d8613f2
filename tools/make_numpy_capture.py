#!/usr/bin/env python3
"""Writes tests/data/numpy_capture: a capture directory v1 made by numpy alone.

It is the interop fixture for `tests/capture_dir.rs`: mmnormd must read it, write it back
byte-identically, and its own simulator must reproduce the samples of this independent
implementation of the documented convention

    h[t] = sum a * exp(+j 2 pi f_t (d + range_offset_m) / c),  d = |TX - p| + |p - RX|,

for one point target of RCS sigma, a = sqrt(sigma / (4 pi)) / (|TX - p| |p - RX|).
Run from the repository root: python3 tools/make_numpy_capture.py
"""
import json
import pathlib

import numpy as np

C = 299_792_458.0
out = pathlib.Path("tests/data/numpy_capture")
out.mkdir(parents=True, exist_ok=True)

f0, df, T = 77.5e9, 5.859375e6, 64
offset = 0.15
target = np.array([0.01, -0.02, 0.05])
sigma = 1e-3
xs = np.arange(-2, 3) * 0.004
tx = np.array([[x, y, 0.4] for y in xs for x in xs], dtype="<f8")
rx = tx + np.array([-0.005, 0.0, 0.0])
d_t = np.linalg.norm(tx - target, axis=1)
d_r = np.linalg.norm(rx - target, axis=1)
amp = np.sqrt(sigma / (4 * np.pi)) / (d_t * d_r)
f = f0 + np.arange(T) * df
h = amp[:, None] * np.exp(1j * 2 * np.pi * f[None, :] * (d_t + d_r + offset)[:, None] / C)
np.save(out / "tx.npy", tx)
np.save(out / "rx.npy", rx)
np.save(out / "samples.npy", h.astype("<c8"))
meta = {
    "format": "mmnorm-capture",
    "version": 1,
    "start_frequency_hz": f0,
    "frequency_step_hz": df,
    "samples_per_chirp": T,
    "range_offset_m": offset,
    "antennas": len(tx),
    "description": "numpy fixture: one point target, 5x5 raster, RX 5 mm from TX",
    "made_by": {"tool": "tools/make_numpy_capture.py", "numpy": np.__version__},
    "point_target": {"position_m": target.tolist(), "rcs_m2": sigma},
}
(out / "capture.json").write_text(json.dumps(meta, indent=2) + "\n")
