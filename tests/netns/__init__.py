"""Multi-host test harness: hosts in network namespaces on one bridge (see hosts.py).

Tests import it as `netns` (pytest puts tests/ on sys.path) and make a fixture:

    from netns import hosts_fixture
    netns_hosts = hosts_fixture(2)          # the fixture's name is the variable's

    def test_netns_something(netns_hosts): ...

Multi-host tests carry `netns` in their names so `pytest -k netns` selects them.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator
from typing import Any

__all__ = ["HarnessError", "Hosts", "cleanup_stale", "hosts_fixture", "require_command", "require_root"]


def __getattr__(name: str) -> Any:
    # Imported on first use, so `python -m tests.netns.hosts` does not load hosts.py twice.
    if name in __all__:
        return getattr(importlib.import_module(f"{__name__}.hosts"), name)
    raise AttributeError(name)


def hosts_fixture(n: int, prefix: str = "skel") -> Callable[..., Any]:
    """A pytest fixture giving a fresh `Hosts(n)` per test, removed after it, pass or fail."""
    import pytest  # here, so the command line (python -m tests.netns.hosts) runs without pytest

    from .hosts import Hosts, cleanup_stale, require_root

    @pytest.fixture
    def _hosts() -> Iterator[Hosts]:
        require_root()
        cleanup_stale(prefix)  # a crashed earlier run must not hold the names or the memory
        with Hosts(n, prefix) as hosts:
            yield hosts

    return _hosts
