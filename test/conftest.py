"""Shared pytest fixtures: where the real robot logs live (../shared/data), loaded once."""

from pathlib import Path
from typing import Callable

import pytest

from laser_odom.core.datasets import (
    discover_datasets, load_dataset, subsampled_datasets)
from laser_odom.core.trajectory import Dataset

#: The real logs sit beside the repository, never inside it (see shared/data/README.md).
SHARED_DATA_DIR = Path(__file__).resolve().parents[1].parent / 'shared' / 'data'


@pytest.fixture(scope='session')
def shared_data_dir() -> Path:
    """Return ../shared/data, or skip the test when the real logs are not available."""
    if not SHARED_DATA_DIR.is_dir():
        pytest.skip(f'real robot logs not available ({SHARED_DATA_DIR} does not exist)')
    return SHARED_DATA_DIR


@pytest.fixture(scope='session')
def real_log(shared_data_dir) -> Callable[[str], Dataset]:
    """Return a loader of the real logs by benchmark name (``fr079/5`` too), each loaded once.

    A log missing under ../shared/data skips the test that asks for it.
    """
    found = discover_datasets(shared_data_dir)
    subsampled = subsampled_datasets(found)
    cache: dict[str, Dataset] = {}

    def load(name: str) -> Dataset:
        if name not in cache:
            if name in subsampled:
                spec = subsampled[name]
                cache[name] = spec.derive(load(spec.base), name)
            elif name in found:
                cache[name] = load_dataset(found[name], name=name)
            else:
                pytest.skip(f'real log {name} not found under {shared_data_dir}')
        return cache[name]
    return load


@pytest.fixture
def context():
    """Return a private rclpy context on a domain of its own (pytest keeps Ctrl-C)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    from node_harness import unique_domain_id
    ctx = Context()
    rclpy.init(context=ctx, domain_id=unique_domain_id(),
               signal_handler_options=SignalHandlerOptions.NO)
    yield ctx
    rclpy.try_shutdown(context=ctx)


@pytest.fixture(scope='module')
def peer(request):
    """Return a test-side rclpy peer on the test module's ``DOMAIN``."""
    from node_harness import Peer
    test_peer = Peer(request.module.DOMAIN)
    yield test_peer
    test_peer.close()
