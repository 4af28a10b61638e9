import pytest

from twin.controllers.lmi import design_balance_gains


@pytest.fixture(scope="session")
def design():
    """The default LMI design on the nominal parameters (solved once per test session)."""
    return design_balance_gains()
