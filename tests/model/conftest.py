"""Fixtures of the model tests: the cache of the ANCF reference runs (issue 19)."""

import pytest


@pytest.fixture(scope="module")
def ref_cache(pytestconfig):
    """pytest's cache directory for reference runs that are not committed under their
    current key in tests/reference_runs/ (tests/fidelity_cases.py, ``reference_run``)."""
    return pytestconfig.cache.mkdir("casflex_ancf_reference")
