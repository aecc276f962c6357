"""Shared fixtures (helpers live in ``tests/support``; nothing is imported from here)."""

from __future__ import annotations

import pytest

from support.lti import random_lti


@pytest.fixture
def lti_factory():
    """``random_lti(n, m, p, seed, radius=0.9, feedthrough=False)``."""
    return random_lti
