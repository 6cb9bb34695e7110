"""Shared test setup: JAX's persistent compilation cache (compiles dominate test time) and
session-scoped fixtures so that compiled functions are shared across tests."""

from __future__ import annotations

import os

# Tests check behaviour, never speed, and compiling dominates their time: XLA compiles at its lowest
# optimisation level (on this CPU about 30 % less CPU time for a training test). Set before JAX
# starts; the commands the tests start inherit it.
TEST_XLA_FLAGS = "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + TEST_XLA_FLAGS).strip()

import jax  # noqa: E402
import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

# Property tests draw the same examples on every run (CI reruns a clean clone at each stop: a new
# draw must not turn it red by chance); ``HYPOTHESIS_PROFILE=explore`` draws new ones, to search.
settings.register_profile("repro", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repro"))

_CACHE = os.environ.get("PARALLEL_SKILLS_TEST_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "parallel_skills_jax"))
jax.config.update("jax_compilation_cache_dir", _CACHE)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


@pytest.fixture
def one_core():
    """Pin the test process to one core while the test runs: MJX-jax can deadlock on this 2-core
    CPU otherwise (shared/STACK.md)."""
    if not hasattr(os, "sched_setaffinity"):
        yield
        return
    saved = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(saved)})
    try:
        yield
    finally:
        os.sched_setaffinity(0, saved)


@pytest.hookimpl(optionalhook=True)  # (a hook of pytest-xdist: unknown under -p no:xdist)
def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (pyproject's addopts): one worker per core this process may run on, at most 4 (a
    worker compiling a training iteration holds up to ~5 GB)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(4, cores))
