"""Fixtures of the model tests: the cache of the ANCF reference runs (issue 19)."""

import pytest


@pytest.fixture(scope="module")
def ref_cache(pytestconfig):
    """pytest's cache directory for reference runs, keyed by the reference's source, the
    move, the element count and the step (tests/fidelity_cases.py)."""
    return pytestconfig.cache.mkdir("casflex_ancf_reference")
