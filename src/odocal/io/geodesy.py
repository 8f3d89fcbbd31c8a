"""Latitude/longitude/altitude to a local East-North-Up frame, with pymap3d (WGS84)."""

from __future__ import annotations

import numpy as np
import pymap3d

from odocal.arrays import FloatArray
from odocal.errors import DataError


def check_lla(lat: FloatArray, lon: FloatArray, *, stream: str) -> None:
    """Reject positions that are not latitude/longitude in degrees."""
    ok = np.isfinite(lat) & np.isfinite(lon)
    if not ok.any():
        raise DataError(f"stream '{stream}': no valid latitude/longitude")
    if np.any(np.abs(lat[ok]) > 90.0) or np.any(np.abs(lon[ok]) > 180.0):
        raise DataError(f"stream '{stream}': latitude/longitude out of range (|lat| <= 90, "
                        "|lon| <= 180 degrees); are they in radians or a projected frame?")


def lla_to_enu(lat_deg: FloatArray, lon_deg: FloatArray, alt_m: FloatArray,
               origin: tuple[float, float, float]) -> tuple[FloatArray, FloatArray, FloatArray]:
    """East, north, up (m) of WGS84 points relative to ``origin`` (lat deg, lon deg, alt m)."""
    e, n, u = pymap3d.geodetic2enu(lat_deg, lon_deg, alt_m, *origin)
    return np.asarray(e, dtype=np.float64), np.asarray(n, dtype=np.float64), \
        np.asarray(u, dtype=np.float64)


def ecef_to_enu(x: FloatArray, y: FloatArray, z: FloatArray,
                origin: tuple[float, float, float]) -> tuple[FloatArray, FloatArray, FloatArray]:
    """ECEF positions (m) to ENU (m) about ``origin``."""
    e, n, u = pymap3d.ecef2enu(x, y, z, *origin)
    return np.asarray(e, dtype=np.float64), np.asarray(n, dtype=np.float64), \
        np.asarray(u, dtype=np.float64)


def ecef_vectors_to_enu(vx: FloatArray, vy: FloatArray, vz: FloatArray,
                        origin: tuple[float, float, float]
                        ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """ECEF direction vectors (velocities, axes) to ENU components about ``origin``."""
    e, n, u = pymap3d.ecef2enuv(vx, vy, vz, origin[0], origin[1])
    return np.asarray(e, dtype=np.float64), np.asarray(n, dtype=np.float64), \
        np.asarray(u, dtype=np.float64)


def ecef_origin(x: float, y: float, z: float) -> tuple[float, float, float]:
    """Latitude, longitude (deg) and altitude (m) of an ECEF point."""
    lat, lon, alt = pymap3d.ecef2geodetic(x, y, z)
    return float(lat), float(lon), float(alt)
