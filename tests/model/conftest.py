"""Fixtures of the model tests: the cache of the ANCF reference runs (issue 19)."""

import pytest


@pytest.fixture(scope="module")
def ref_cache(pytestconfig, tmp_path_factory):
    """pytest's cache directory for reference runs that are not committed under their
    current key in tests/reference_runs/ (tests/fidelity_cases.py, ``reference_run``); a
    temporary one when pytest runs without its cache (``-p no:cacheprovider``)."""
    cache = getattr(pytestconfig, "cache", None)
    if cache is None:
        return tmp_path_factory.mktemp("casflex_ancf_reference")
    return cache.mkdir("casflex_ancf_reference")
