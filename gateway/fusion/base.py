"""The one interface every attitude filter implements (settings + state + update, plus a batch run)."""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


class AttitudeFilter(ABC):
    """Estimates the body-to-earth (ENU) quaternion `w, x, y, z` from gyroscope, accelerometer and magnetometer.

    Subclasses hold a frozen settings dataclass and mutable state. 6D mode is chosen per call by passing
    `mag_uT=None`; a filter created with `use_mag=False` ignores the magnetometer altogether.
    """

    name: str = "base"

    def __init__(self, *, use_mag: bool = True) -> None:
        self.use_mag = use_mag

    @abstractmethod
    def initialise(self, acc_m_s2: FloatArray, mag_uT: FloatArray | None) -> None:
        """Set the attitude from a mean accelerometer (and magnetometer) reading taken at rest."""

    @abstractmethod
    def update(
        self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float
    ) -> FloatArray:
        """Advance by one sample of `dt_s` seconds and return the new quaternion, shape (4,)."""

    @property
    @abstractmethod
    def quaternion(self) -> FloatArray:
        """Current attitude estimate, shape (4,), scalar first."""

    def run(
        self,
        gyr_rad_s: FloatArray,
        acc_m_s2: FloatArray,
        mag_uT: FloatArray | None,
        dt_s: float,
    ) -> FloatArray:
        """Filter whole arrays of shape (N, 3); returns (N, 4). Subclasses may override for speed."""
        n = gyr_rad_s.shape[0]
        out = np.empty((n, 4))
        use_mag = self.use_mag and mag_uT is not None
        for i in range(n):
            out[i] = self.update(gyr_rad_s[i], acc_m_s2[i], mag_uT[i] if use_mag else None, dt_s)  # type: ignore[index]
        return out
