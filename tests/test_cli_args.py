"""Shared command-line argument types."""

from __future__ import annotations

import argparse

import pytest

from tmr.cli_args import positive_float, positive_int


def test_positive_int():
    assert positive_int("3") == 3
    for bad in ("0", "-2", "2.5", "x", ""):
        with pytest.raises(argparse.ArgumentTypeError):
            positive_int(bad)


def test_positive_float():
    assert positive_float("0.25") == 0.25
    for bad in ("0", "-1", "nan", "inf", "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            positive_float(bad)
