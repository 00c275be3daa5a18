"""The station rig the page's tests serve from."""
import pytest

from tests.support.station_rig import Rig


@pytest.fixture
def rig(tmp_path):
    r = Rig(tmp_path)  # no robot on the cable until a test starts one: commands wait, the page serves
    yield r
    r.close()
