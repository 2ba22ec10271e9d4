"""Test isolation shared by every module."""
import logging

import pytest

_LOG = logging.getLogger("diffsurf")
#: the 'diffsurf' logger as the package leaves it (no handler, propagating), taken when pytest
#: loads this file, before any test or fixture has run the CLI
_PRISTINE = (_LOG.handlers[:], _LOG.level, _LOG.propagate, _LOG.disabled)


def _restore():
    _LOG.handlers[:] = _PRISTINE[0]
    _LOG.setLevel(_PRISTINE[1])
    _LOG.propagate, _LOG.disabled = _PRISTINE[2], _PRISTINE[3]


@pytest.fixture(autouse=True)
def _diffsurf_logger_restored():
    """A CLI run in-process (click's CliRunner) gives the 'diffsurf' logger a stderr handler and
    stops its propagation, as a real process should. Put it back as the package leaves it,
    before and after each test: a module-scoped fixture that ran the CLI did so before this
    fixture could take a snapshot, so the state to restore is the one taken at load time, and
    a test's caplog (which listens at the root) then sees the records whatever ran before."""
    _restore()
    yield
    _restore()
