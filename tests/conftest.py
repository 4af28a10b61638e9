import os

# One BLAS thread in each test process (and the commands the tests start, which inherit it):
# the suite runs a process per core (pytest-xdist), and OpenBLAS's own threads, one per core in
# each process, then fight over the cores, spinning while they wait (the two calibration files
# took 85 s instead of 55 s side by side). Set before the workers import numpy; results are the
# same bytes either way (the refactor hashes and golden files hold under it).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest  # noqa: E402

from twin.controllers.lmi import design_balance_gains


@pytest.fixture(scope="session", autouse=True)
def _private_design_cache(tmp_path_factory):
    """Every design the session caches (in this process and in the subprocesses it starts,
    which inherit the environment) goes to a directory of its own: the tests must neither
    write into the user's cache nor be served designs from it."""
    old = os.environ.get("TWIN_CACHE_DIR")
    os.environ["TWIN_CACHE_DIR"] = str(tmp_path_factory.mktemp("design-cache"))
    yield
    if old is None:
        os.environ.pop("TWIN_CACHE_DIR", None)
    else:
        os.environ["TWIN_CACHE_DIR"] = old


@pytest.fixture(scope="session")
def design():
    """The default LMI design on the nominal parameters (solved once per test session)."""
    return design_balance_gains()
