"""Ride metrics from IMU traces: the paper's vibration degree g, ISO 2631-1 aw and comfort band,
rms_az, peak |az|.

Vibration degree (Zhang et al.)::

    g(t) = sqrt(wx'(t)^2 + wy'(t)^2 + alpha * az'(t)^2),   alpha = 0.1

with wx, wy the body roll and pitch rates (rad/s) and az the vertical specific force (m/s^2) of
the body-fixed IMU. **The primes are deviations from the undisturbed run**: the same vehicle
(parameters, speed, lateral offset, path, start state, backend, time step) on the same road with
the defect filled in (``prime="baseline"``). Why: a raw IMU signal carries gravity (az ~ 9.81),
the road's own roughness and the path's steady motion; subtracting the twin run removes all of
it exactly and leaves only what the defect caused (g is 0 on an undisturbed road, whatever its
roughness class), so g is comparable across roads and speeds. A high-pass alternative
(``prime="highpass"``: 2nd-order Butterworth at 0.5 Hz, zero phase) is provided for traces
without a twin run; it keeps the roughness response and is only used where asked for.

Scalars over a window (``window_metrics``): ``g`` = RMS of g(t), ``g_peak`` = its maximum,
``g_energy`` = the integral of g^2. The sweep reports a crossing's vibration degree as the peak
and an energy RMS over a common duration (see ``sweep.py`` for why).

ISO 2631-1:1997 frequency weighting Wk (vertical, seated/standing/recumbent comfort) as the
standard's analogue filter, Annex A: band limiting high-pass (f1 = 0.4 Hz, Q1 = 1/sqrt 2) and
low-pass (f2 = 100 Hz, Q2 = 1/sqrt 2), acceleration-velocity transition (f3 = f4 = 12.5 Hz,
Q4 = 0.63), upward step (f5 = 2.37 Hz, Q5 = 0.91, f6 = 3.35 Hz, Q6 = 0.91), K = 1. It is mapped
to a digital filter with the bilinear transform (``scipy.signal.bilinear``); where the IMU rate is
too low to represent the 100 Hz band limit (fs < 240 Hz) that low-pass is left out (the sampled
signal is band limited already). aw = RMS of the weighted az over the window, the filter run
over the whole trace from a steady state (so its 0.4 Hz transient does not leak into the
window); az here is the raw vertical specific force (what an occupant feels; its mean is removed
by the weighting itself).

Comfort bands (ISO 2631-1 Annex C, m/s^2): < 0.315 not uncomfortable; 0.315-0.63 a little
uncomfortable; 0.5-1 fairly uncomfortable; 0.8-1.6 uncomfortable; 1.25-2.5 very uncomfortable;
> 2 extremely uncomfortable. The standard's bands overlap; here each overlap is split at the
geometric mean of its ends (0.561, 0.894, 1.414, 2.236), so every aw gets exactly one band and a
band's core range keeps its name. ``comfort_bands_containing`` lists every band the standard
would allow.

``rms_az`` = RMS of az about its mean over the window (raw signal); ``peak_az`` = max |az - mean|.
"""
from __future__ import annotations

import math

import numpy as np

ALPHA = 0.1
WK = {"f1": 0.4, "q1": 1 / math.sqrt(2), "f2": 100.0, "q2": 1 / math.sqrt(2), "f3": 12.5, "f4": 12.5,
      "q4": 0.63, "f5": 2.37, "q5": 0.91, "f6": 3.35, "q6": 0.91}

# (label, standard's range) and the documented split points of the overlaps
ISO2631_BANDS = (("not uncomfortable", 0.0, 0.315), ("a little uncomfortable", 0.315, 0.63),
                 ("fairly uncomfortable", 0.5, 1.0), ("uncomfortable", 0.8, 1.6),
                 ("very uncomfortable", 1.25, 2.5), ("extremely uncomfortable", 2.0, math.inf))
BAND_EDGES = (0.315, math.sqrt(0.5 * 0.63), math.sqrt(0.8 * 1.0), math.sqrt(1.25 * 1.6), math.sqrt(2.0 * 2.5))


def comfort_band(aw: float) -> str:
    """One ISO 2631-1 comfort label for an aw (m/s^2), overlaps split at geometric means."""
    if not np.isfinite(aw):
        return "n/a"
    for (label, _, _), edge in zip(ISO2631_BANDS, BAND_EDGES):
        if aw < edge:
            return label
    return ISO2631_BANDS[-1][0]


def comfort_bands_containing(aw: float) -> list[str]:
    """Every band of the standard whose (overlapping) range contains aw."""
    return [label for label, lo, hi in ISO2631_BANDS if lo <= aw < hi or (lo == 0 and aw < hi)]


def wk_analog(band_limit_lowpass: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Numerator and denominator polynomials (in s, highest power first) of Wk, K = 1: the
    product of the standard's high-pass, (optional) low-pass, transition and step sections."""
    w = {k: 2 * math.pi * v for k, v in WK.items() if k.startswith("f")}
    q = WK
    highpass = ([1.0, 0.0, 0.0], [1.0, w["f1"] / q["q1"], w["f1"] ** 2])
    lowpass = ([w["f2"] ** 2], [1.0, w["f2"] / q["q2"], w["f2"] ** 2])
    transition = ([w["f4"] ** 2 / w["f3"], w["f4"] ** 2], [1.0, w["f4"] / q["q4"], w["f4"] ** 2])
    step = ([1.0, w["f5"] / q["q5"], w["f5"] ** 2], [1.0, w["f6"] / q["q6"], w["f6"] ** 2])
    sections = (highpass, lowpass, transition, step) if band_limit_lowpass else (highpass, transition, step)
    b, a = np.array([1.0]), np.array([1.0])
    for num, den in sections:
        b, a = np.polymul(b, num), np.polymul(a, den)
    return b, a


def wk_magnitude(f: np.ndarray) -> np.ndarray:
    """|Wk| of the analogue filter at frequencies f (Hz)."""
    b, a = wk_analog()
    s = 2j * np.pi * np.asarray(f, dtype=np.float64)
    return np.abs(np.polyval(b, s) / np.polyval(a, s))


def wk_digital(fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear-transform Wk for sample rate fs (Hz); the 100 Hz band limit only where fs can
    represent it (see the module docs)."""
    from scipy import signal

    return signal.bilinear(*wk_analog(band_limit_lowpass=fs >= 2.4 * WK["f2"]), fs)


def wk_weight(az: np.ndarray, fs: float) -> np.ndarray:
    """Wk-weighted signal, the filter started in the steady state of the first sample."""
    from scipy import signal

    x = np.asarray(az, dtype=np.float64)
    if len(x) == 0:
        return x
    b, a = wk_digital(fs)
    zi = signal.lfilter_zi(b, a) * x[0]
    y, _ = signal.lfilter(b, a, x, zi=zi)
    return y


def highpass(x: np.ndarray, fs: float, fc: float = 0.5) -> np.ndarray:
    from scipy import signal

    sos = signal.butter(2, fc, btype="highpass", fs=fs, output="sos")
    return signal.sosfiltfilt(sos, np.asarray(x, dtype=np.float64), axis=0)


def vibration_degree(gyro: np.ndarray, acc: np.ndarray, gyro_ref: np.ndarray | None = None,
                     acc_ref: np.ndarray | None = None, fs: float | None = None, alpha: float = ALPHA,
                     prime: str = "baseline") -> np.ndarray:
    """g(t) from (T,3) body-frame angular rates and specific forces (see module docs)."""
    gyro = np.asarray(gyro, dtype=np.float64)
    acc = np.asarray(acc, dtype=np.float64)
    if prime == "baseline":
        if gyro_ref is None or acc_ref is None:
            raise ValueError("prime='baseline' needs the undisturbed run's traces")
        wx = gyro[:, 0] - gyro_ref[:, 0]
        wy = gyro[:, 1] - gyro_ref[:, 1]
        az = acc[:, 2] - acc_ref[:, 2]
    elif prime == "highpass":
        if fs is None:
            raise ValueError("prime='highpass' needs the sample rate")
        hp = highpass(np.column_stack([gyro[:, 0], gyro[:, 1], acc[:, 2]]), fs)
        wx, wy, az = hp[:, 0], hp[:, 1], hp[:, 2]
    else:
        raise ValueError(f"unknown prime {prime!r} (baseline or highpass)")
    return np.sqrt(wx ** 2 + wy ** 2 + alpha * az ** 2)


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x ** 2))) if len(x) else float("nan")


def window_metrics(t: np.ndarray, acc: np.ndarray, gyro: np.ndarray, window: tuple[float, float],
                   acc_ref: np.ndarray | None = None, gyro_ref: np.ndarray | None = None,
                   prime: str = "baseline", alpha: float = ALPHA) -> dict:
    """g, g_peak, aw, comfort band, rms_az, peak_az over ``window`` (s) of one trace.

    ``t`` (T,), ``acc``/``gyro`` (T,3); NaN samples (a run that ended early) are ignored.
    """
    t = np.asarray(t, dtype=np.float64)
    ok = np.isfinite(acc[:, 2])
    if acc_ref is not None:
        ok &= np.isfinite(acc_ref[:, 2])
    if ok.sum() < 4:
        nan = float("nan")
        return {"g": nan, "g_peak": nan, "g_energy": nan, "aw": nan, "comfort": "n/a", "rms_az": nan, "peak_az": nan}
    fs = 1.0 / float(np.median(np.diff(t)))
    n = int(np.flatnonzero(ok)[-1]) + 1  # valid prefix
    t, acc, gyro = t[:n], acc[:n], gyro[:n]
    if acc_ref is not None:
        acc_ref, gyro_ref = acc_ref[:n], gyro_ref[:n]
    m = (t >= window[0]) & (t <= window[1])
    g = vibration_degree(gyro, acc, gyro_ref, acc_ref, fs=fs, alpha=alpha, prime=prime)
    az = acc[:, 2]
    aw_sig = wk_weight(az, fs)
    azw = az[m] - az[m].mean() if m.any() else np.array([np.nan])
    aw = _rms(aw_sig[m]) if m.any() else float("nan")
    dt = 1.0 / fs
    return {"g": _rms(g[m]) if m.any() else float("nan"), "g_peak": float(np.nanmax(g[m])) if m.any() else float("nan"),
            "g_energy": float(np.nansum(g[m] ** 2) * dt) if m.any() else float("nan"),
            "aw": aw, "comfort": comfort_band(aw), "rms_az": _rms(azw),
            "peak_az": float(np.nanmax(np.abs(azw))) if m.any() else float("nan")}
