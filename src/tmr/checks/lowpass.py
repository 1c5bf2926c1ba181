"""Zero-phase Butterworth low-pass filter for the exported trajectories
(:func:`tmr.checks.metrics.filter_trajectories`).

Textbook definitions (Oppenheim & Schafer, *Discrete-Time Signal Processing*, 3rd ed., 2010, §7.1 and §6.5):

* :func:`butter_lowpass`: the analog Butterworth prototype's poles −exp(iπ m / 2n), m = −n+1, −n+3, …, n−1, scaled
  to the pre-warped cut-off 2 f_s tan(π f_c / f_s) and mapped by the bilinear transform z = (2 f_s + s)/(2 f_s − s);
  the n zeros go to z = −1 and the gain makes the DC gain exactly 1;
* :func:`lfilter`: the direct form II transposed difference equation, with initial state ``zi``;
* :func:`filtfilt`: forward then backward pass over the signal extended by odd reflection, each pass started in
  the filter's steady state for the first sample (Gustafsson's forward-backward scheme as in MATLAB and scipy).

The same numbers as ``scipy.signal.butter`` and ``scipy.signal.filtfilt(..., padtype="odd")`` to rounding
(``tests/test_lowpass.py``); written here because importing ``scipy.signal`` takes 0.3–0.7 s, more than a third of
a whole ``tmr.plan`` run (``benchmarks/results/end_to_end.md``), while the filter itself takes milliseconds.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tmr.errors import ParameterError

Array = NDArray[np.float64]

__all__ = ["butter_lowpass", "filtfilt", "lfilter"]


def butter_lowpass(order: int, cutoff_hz: float, fs: float) -> tuple[Array, Array]:
    """Digital Butterworth low-pass of ``order`` with −3 dB cut-off ``cutoff_hz`` [Hz] at sample rate ``fs`` [Hz].

    Returns ``(b, a)``: numerator and denominator polynomial coefficients in z⁻¹ (``a[0] == 1``).
    """
    n = int(order)
    if n < 1:
        raise ParameterError(f"filter order must be >= 1, got {order!r}")
    if not (0.0 < cutoff_hz < 0.5 * fs):
        raise ParameterError(f"cut-off {cutoff_hz!r} Hz must be in ]0, {0.5 * fs:g}[ (the Nyquist frequency)")
    m = np.arange(-n + 1, n, 2)
    prototype = -np.exp(1j * math.pi * m / (2 * n))  # analog poles on the unit circle, left half-plane
    fs2 = 4.0  # scipy's convention: normalised frequencies, bilinear transform at fs = 2
    warped = fs2 * math.tan(math.pi * cutoff_hz / fs)
    poles_s = warped * prototype
    poles_z = (fs2 + poles_s) / (fs2 - poles_s)
    gain = warped**n * float(np.real(1.0 / np.prod(fs2 - poles_s)))
    b = gain * np.real(np.poly(-np.ones(n)))
    a = np.real(np.poly(poles_z))
    return b, a


def lfilter(b: Array, a: Array, x: Array, zi: Array) -> Array:
    """Filter ``x`` along axis 0 with y[k] = b[0] x[k] + z_0, z_j ← b[j+1] x[k] + z_{j+1} − a[j+1] y[k].

    Args:
        b, a: coefficients, ``len(b) == len(a) >= 2`` (order ≥ 1), ``a[0] == 1``.
        x: (K, ...) signal.
        zi: (len(a) − 1, ...) initial state.
    """
    y = np.empty_like(x)
    z = np.array(zi, dtype=float, copy=True)
    order = len(a) - 1
    b0 = b[0]
    for k in range(x.shape[0]):
        xk = x[k]
        yk = b0 * xk + z[0]
        for j in range(order - 1):
            z[j] = b[j + 1] * xk + z[j + 1] - a[j + 1] * yk
        z[order - 1] = b[order] * xk - a[order] * yk
        y[k] = yk
    return y


def _steady_state(b: Array, a: Array) -> Array:
    """Initial state of :func:`lfilter` for a unit step already at rest: solve (I − Aᵀ) zi = b[1:] − a[1:] b[0],
    A the companion matrix of ``a`` (scipy's ``lfilter_zi``)."""
    n = len(a) - 1
    companion = np.zeros((n, n))
    companion[0] = -a[1:]
    companion[1:, :-1] += np.eye(n - 1)
    return np.linalg.solve(np.eye(n) - companion.T, b[1:] - a[1:] * b[0])


def filtfilt(b: ArrayLike, a: ArrayLike, x: ArrayLike, padlen: int) -> Array:
    """Zero-phase filtering of ``x`` along axis 0: odd extension by ``padlen`` samples at each end, forward and
    backward :func:`lfilter` passes started in steady state, the extension cut off again.

    Args:
        b, a: filter coefficients (``a[0] != 0``; both are normalised by it).
        x: (K, ...) signal, K > ``padlen``.
        padlen: samples of odd extension at each end, 0 ≤ padlen < K.
    """
    b_arr = np.asarray(b, dtype=float)
    a_arr = np.asarray(a, dtype=float)
    b_arr, a_arr = b_arr / a_arr[0], a_arr / a_arr[0]
    if max(len(a_arr), len(b_arr)) < 2:
        raise ParameterError("filtfilt needs a filter of order >= 1 (at least two coefficients)")
    x_arr = np.asarray(x, dtype=float)
    if not (0 <= padlen < x_arr.shape[0]):
        raise ParameterError(f"padlen must be in [0, {x_arr.shape[0]}[, got {padlen}")
    n = max(len(a_arr), len(b_arr))
    b_arr = np.pad(b_arr, (0, n - len(b_arr)))
    a_arr = np.pad(a_arr, (0, n - len(a_arr)))
    if padlen:
        head = 2.0 * x_arr[0] - x_arr[padlen:0:-1]
        tail = 2.0 * x_arr[-1] - x_arr[-2 : -padlen - 2 : -1]
        ext = np.concatenate([head, x_arr, tail])
    else:
        ext = x_arr
    zi = _steady_state(b_arr, a_arr).reshape((n - 1,) + (1,) * (x_arr.ndim - 1))
    forward = lfilter(b_arr, a_arr, ext, zi * ext[0])
    backward = lfilter(b_arr, a_arr, forward[::-1], zi * forward[-1])[::-1]
    return backward[padlen : backward.shape[0] - padlen] if padlen else backward
