"""The ``backend`` fixture: detector tests that take it run on every array backend here."""

import pytest
from array_backends import ARRAY_BACKENDS, skip_unless_runnable


@pytest.fixture(params=ARRAY_BACKENDS)
def backend(request):
    skip_unless_runnable(request.param)
    return request.param
