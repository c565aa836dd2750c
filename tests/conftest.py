"""Shared fixtures: long closed-loop runs are simulated once per session."""
import functools

import pytest

from models import CONTROLLER_A, hypothesis, simulate


@functools.lru_cache(maxsize=None)
def _cycle(name, t_end=40.0, dt=2e-4, **overrides):
    return simulate(hypothesis(name, **overrides), CONTROLLER_A, t_end, dt=dt)


@pytest.fixture(scope="session")
def cycle_at_a():
    """``cycle_at_a(name, **overrides)``: a 40 s controller-A run (cached), for features."""

    def get(name, **overrides):
        return _cycle(name, **overrides)

    return get


def pytest_collection_modifyitems(session, config, items):
    """Files that set ``RUN_FIRST`` (their rough minutes on one core) are collected first, longest
    first: on two xdist workers (a file each) a long file started last would run alone at the end.
    Only the two longest set it: xdist gives each worker two files at the start, and a third long
    one would queue behind the first on the same worker."""
    items.sort(key=lambda item: -getattr(getattr(item, "module", None), "RUN_FIRST", 0))
