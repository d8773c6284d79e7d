"""Shared fixtures."""

from __future__ import annotations

import signal

import pytest


@pytest.fixture
def sigint_handler():
    """Make SIGINT raise KeyboardInterrupt in this process for the test's duration.

    A shell without job control starts background commands with SIGINT ignored, and Python then
    keeps it ignored: a test that sends itself SIGINT would wait forever (CI may run so).
    """
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)

