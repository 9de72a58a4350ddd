"""Camera geodetic pose: conventions and exact WGS84 conversion."""

import math

import numpy as np
import pytest

from dronekey.daemon.geo import CameraGeo, GeoError


def test_level_camera_looking_north():
    geo = CameraGeo(48.0, 11.0, 500.0)
    lat, lon, alt = geo.geodetic([0.0, 0.0, 1000.0])  # 1 km straight ahead
    assert lat > 48.0 and lon == pytest.approx(11.0, abs=1e-9)
    assert (lat - 48.0) * 111_200 == pytest.approx(1000.0, rel=0.01)
    assert alt == pytest.approx(500.0 + 1000.0**2 / (2 * 6.37e6), abs=0.05)  # Earth curves away


def test_yaw_east_and_pitch_up():
    geo = CameraGeo(0.0, 0.0, 0.0, yaw_deg=90.0, pitch_deg=30.0)
    ned = geo.ned_from_cam([0.0, 0.0, 1.0])
    assert np.allclose(ned, [0.0, math.cos(math.radians(30)), -0.5], atol=1e-12)
    # image-down (camera +y) points below the horizon when pitched up.
    assert geo.ned_from_cam([0.0, 1.0, 0.0])[2] > 0


def test_roundtrip_zero_offset():
    geo = CameraGeo(-33.9, 151.2, 40.0, 10, 5, 0)
    lat, lon, alt = geo.geodetic([0.0, 0.0, 0.0])
    assert (lat, lon) == pytest.approx((-33.9, 151.2), abs=1e-10) and alt == pytest.approx(40.0, abs=1e-6)


@pytest.mark.parametrize("text", ["1,2", "a,b,c", "95,0,0", "0,0,0,0,120,0"])
def test_parse_errors(text):
    with pytest.raises(GeoError):
        CameraGeo.parse(text)
