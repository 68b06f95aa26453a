"""Shared pytest fixtures: where the real robot logs live (../shared/data)."""

from pathlib import Path

import pytest

#: The real logs sit beside the repository, never inside it (see shared/data/README.md).
SHARED_DATA_DIR = Path(__file__).resolve().parents[1].parent / 'shared' / 'data'


@pytest.fixture(scope='session')
def shared_data_dir() -> Path:
    """Return ../shared/data, or skip the test when the real logs are not available."""
    if not SHARED_DATA_DIR.is_dir():
        pytest.skip(f'real robot logs not available ({SHARED_DATA_DIR} does not exist)')
    return SHARED_DATA_DIR
