"""Test isolation shared by every module."""
import logging

import pytest


@pytest.fixture(autouse=True)
def _diffsurf_logger_restored():
    """A CLI run in-process (click's CliRunner) gives the 'diffsurf' logger a stderr handler and
    stops its propagation, as a real process should; put it back after each test, so a later
    test's caplog (which listens at the root) sees the records whatever ran before it."""
    log = logging.getLogger("diffsurf")
    saved = (log.handlers[:], log.level, log.propagate)
    yield
    log.handlers[:], log.level, log.propagate = saved[0], saved[1], saved[2]
