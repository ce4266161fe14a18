import os

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def rich_duty():
    from etb_gym.excitation import rich_excitation

    return rich_excitation()
