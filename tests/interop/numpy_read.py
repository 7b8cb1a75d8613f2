"""numpy over what mmnormd writes for other tools: a capture directory (samples.npy, tx.npy,
rx.npy, capture.json), and `capture decode` of an adc_data.bin that numpy writes itself in TI's
4-lane, I-first layout (each sample instant: I of RX 0..3, then Q of RX 0..3, int16 LE).
Usage: numpy_read.py capture DIR | numpy_read.py write FILE F C R S |
numpy_read.py decoded DIR FILE F C R S"""
import json
import sys

import numpy as np


def capture(path):
    meta = json.load(open(f"{path}/capture.json"))
    samples = np.load(f"{path}/samples.npy")
    tx = np.load(f"{path}/tx.npy")
    rx = np.load(f"{path}/rx.npy")
    print(f"capture {path}: samples {samples.shape} {samples.dtype}, tx {tx.shape} {tx.dtype}, "
          f"rx {rx.shape}; capture.json keys {sorted(meta)[:8]}")
    assert samples.dtype == np.complex64 and samples.ndim == 2
    assert tx.shape == (samples.shape[0], 3) and rx.shape == tx.shape and tx.dtype == np.float64
    assert np.isfinite(samples).all() and np.abs(samples).max() > 0
    spectrum = np.abs(np.fft.fft(samples, axis=1)).mean(axis=0)
    print(f"  mean range spectrum peaks in bin {int(spectrum.argmax())} of {samples.shape[1]}")


def tones(shape):
    """A different tone and amplitude per frame, chirp and receiver, quantised to int16."""
    frames, chirps, rx, samples = shape
    f, c, r, s = np.meshgrid(*(np.arange(n) for n in shape), indexing="ij")
    amplitude = 1000.0 * (1 + r) + 10.0 * f + c
    phase = 2 * np.pi * (5 + 7 * r + f) * s / samples
    i = np.round(amplitude * np.cos(phase)).astype(np.int16)
    q = np.round(amplitude * np.sin(phase)).astype(np.int16)
    return i, q


def write(path, shape):
    i, q = tones(shape)
    # (frame, chirp, rx, sample) -> (frame, chirp, sample, [I rx0..3, Q rx0..3])
    words = np.concatenate([i.transpose(0, 1, 3, 2), q.transpose(0, 1, 3, 2)], axis=3)
    words.astype("<i2").tofile(path)
    print(f"wrote {path}: {words.size * 2} bytes, {shape} in the 4-lane I-first layout")


def decoded(path, raw, shape):
    samples = np.load(f"{path}/samples.npy")
    i, q = tones(shape)
    expected = (i + 1j * q).astype(np.complex64)
    print(f"decoded {path}: {samples.shape} {samples.dtype}, largest difference from what numpy "
          f"wrote {np.abs(samples - expected).max() if samples.shape == shape else 'n/a'}")
    assert samples.dtype == np.complex64
    assert samples.shape == shape, (samples.shape, shape)
    assert np.array_equal(samples, expected)


if __name__ == "__main__":
    if sys.argv[1] == "capture":
        capture(sys.argv[2])
    elif sys.argv[1] == "write":
        write(sys.argv[2], tuple(int(v) for v in sys.argv[3:7]))
    else:
        decoded(sys.argv[2], sys.argv[3], tuple(int(v) for v in sys.argv[4:8]))
    print("numpy: all checks passed")
