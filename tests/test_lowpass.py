"""Tests of tmr.checks.lowpass: the Butterworth design and the zero-phase filter against their definitions and
scipy.signal."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from tmr.checks.lowpass import butter_lowpass, filtfilt, lfilter
from tmr.errors import ParameterError


@pytest.mark.parametrize("order", [1, 2, 3, 4, 6])
def test_butterworth_response(order: int) -> None:
    """DC gain 1, −3 dB at the cut-off, maximally flat: |H|² = 1 / (1 + (tan(πf/fs) / tan(πfc/fs))^(2n))."""
    fs, fc = 20.0, 1.3
    b, a = butter_lowpass(order, fc, fs)
    f = np.array([0.0, 0.4, fc, 3.0, 7.0])
    z = np.exp(-2j * np.pi * f / fs)
    h = np.polyval(b[::-1], z) / np.polyval(a[::-1], z)
    ratio = np.tan(np.pi * f / fs) / np.tan(np.pi * fc / fs)
    np.testing.assert_allclose(np.abs(h) ** 2, 1.0 / (1.0 + ratio ** (2 * order)), atol=1e-12)
    assert np.all(np.abs(np.roots(a)) < 1.0)  # stable


@pytest.mark.parametrize("order", [1, 2, 5])
def test_butterworth_matches_scipy(order: int) -> None:
    b, a = butter_lowpass(order, 1.0, 20.0)
    b_ref, a_ref = signal.butter(order, 1.0, btype="low", fs=20.0)
    np.testing.assert_allclose(b, b_ref, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(a, a_ref, rtol=1e-12, atol=1e-15)


def test_lfilter_difference_equation() -> None:
    """Direct form: a0 y[k] = Σ b_j x[k−j] − Σ_{j≥1} a_j y[k−j], from rest."""
    b, a = butter_lowpass(3, 2.0, 25.0)
    x = np.random.default_rng(1).normal(size=60)
    y = lfilter(b, a, x, np.zeros(3))
    ref = np.zeros_like(x)
    for k in range(len(x)):
        past = sum(a[j] * ref[k - j] for j in range(1, 4) if k >= j)
        ref[k] = sum(b[j] * x[k - j] for j in range(4) if k >= j) - past
    np.testing.assert_allclose(y, ref, atol=1e-12)


@pytest.mark.parametrize("padlen", [0, 6, 80])
def test_filtfilt_matches_scipy(padlen: int) -> None:
    x = np.cumsum(np.random.default_rng(padlen).normal(size=(300, 3, 2)), axis=0)
    b, a = butter_lowpass(2, 1.0, 20.0)
    ref = signal.filtfilt(b, a, x, axis=0, padtype="odd", padlen=padlen)
    np.testing.assert_allclose(filtfilt(b, a, x, padlen=padlen), ref, atol=1e-10)


def test_filtfilt_keeps_a_straight_line() -> None:
    """Odd extension continues a line exactly and the steady-state start leaves it unchanged."""
    t = np.linspace(0.0, 10.0, 201)
    x = np.stack([0.3 + 0.7 * t, -2.0 * t], axis=1)
    np.testing.assert_allclose(filtfilt(*butter_lowpass(2, 1.0, 20.0), x, padlen=80), x, atol=1e-6)


def test_bad_input() -> None:
    with pytest.raises(ParameterError, match="Nyquist"):
        butter_lowpass(2, 10.0, 20.0)
    with pytest.raises(ParameterError, match="order"):
        butter_lowpass(0, 1.0, 20.0)
    with pytest.raises(ParameterError, match="padlen"):
        filtfilt([1.0, 1.0], [1.0, 0.5], np.zeros(5), padlen=5)
    with pytest.raises(ParameterError, match="order >= 1"):
        filtfilt([1.0], [1.0], np.zeros(5), padlen=2)
