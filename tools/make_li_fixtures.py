#!/usr/bin/env python3
"""Writes tests/data/li_threshold.json: arrays and scikit-image's threshold_li for each.

The fixture for `recon::threshold` (mmNorm §3.2 / docs/mmnorm-reference.md §4): mmnormd's own Li
implementation must agree with scikit-image on these. Run from the repository root with
numpy and scikit-image installed: python3 tools/make_li_fixtures.py
"""
import json
import pathlib

import numpy as np
import skimage
from skimage.filters import threshold_li

rng = np.random.default_rng(20261123)
cases = {}
cases["lognormal_1000"] = rng.lognormal(0.0, 1.0, 1000)
cases["bimodal_4000"] = np.concatenate([rng.normal(1.0, 0.2, 3000), rng.normal(4.0, 0.5, 1000)])
# |S|^2 of a speckled image with a bright blob: the distribution mmNorm thresholds.
field = np.abs(rng.normal(size=3000) + 1j * rng.normal(size=3000)) * 0.1
field[:300] += np.abs(rng.normal(3.0, 1.0, 300))
cases["power_3000"] = field ** 2
cases["power_exponent_3_5"] = field ** 3.5
cases["shifted_negative_500"] = rng.normal(-50.0, 3.0, 500)
with_nan = rng.uniform(0.0, 10.0, 800)
with_nan[::17] = np.nan
cases["uniform_with_nan_800"] = with_nan
cases["two_values"] = np.array([1.0, 1.0, 1.0, 5.0, 5.0])

out = {"skimage": skimage.__version__, "cases": []}
for name, values in cases.items():
    values = np.asarray(values, dtype=np.float64)
    out["cases"].append({
        "name": name,
        "values": [None if np.isnan(v) else float(v) for v in values],
        "threshold": float(threshold_li(values.copy())),
    })
path = pathlib.Path("tests/data/li_threshold.json")
path.write_text(json.dumps(out) + "\n")
print(path, path.stat().st_size, "bytes")
