"""Step many devices' default filters together: stacked state (N, ...) through one numba call per packet round.

Each device keeps its own sample period and 6D/9D flag; devices join and leave at any time. The kernel runs the very
code path of `DefaultFilter.update_block` per device, so results equal the single-device filter (tested to 1e-9).
"""

from __future__ import annotations

import os

# numba's OpenMP layer spins idle threads between steps by default; on a shared box (gateway, zenoh, web server)
# that burns a core per step for nothing. Must be set before the layer loads, i.e. before the first batched step.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from numpy.typing import NDArray

from gateway.fusion import _default_kernels as K
from gateway.fusion.base import FloatArray
from gateway.fusion.default import DefaultSettings, initial_state

PARALLEL_MIN_SAMPLES = 4000
"""Below this many samples per step (devices × samples) one thread is faster than waking the others."""


class DefaultFilterBatch:
    """N default filters in rows of flat arrays; rows follow `device_ids` (order of joining, compacted on removal)."""

    def __init__(self, settings: DefaultSettings | None = None) -> None:
        self.settings = settings or DefaultSettings()
        self._params = self.settings.to_array()
        self.device_ids: list[str] = []
        self._row: dict[str, int] = {}
        self.states = np.empty((0, K.N_STATE))
        self.dt_s = np.empty(0)
        self.use_mag = np.empty(0, dtype=np.bool_)

    def __len__(self) -> int:
        return len(self.device_ids)

    def add(
        self,
        device_id: str,
        *,
        dt_s: float,
        use_mag: bool = True,
        acc_m_s2: FloatArray | None = None,
        mag_uT: FloatArray | None = None,
    ) -> int:
        """Add a device sampled every `dt_s`; optional mean rest readings initialise it. Returns its row."""
        if device_id in self._row:
            raise ValueError(f"device {device_id!r} already present")
        if not dt_s > 0:
            raise ValueError(f"dt_s must be positive, got {dt_s}")
        state = initial_state(self._params, acc_m_s2, mag_uT if use_mag else None)
        self.states = np.vstack([self.states, state[None]])
        self.dt_s = np.append(self.dt_s, float(dt_s))
        self.use_mag = np.append(self.use_mag, bool(use_mag))
        self._row[device_id] = len(self.device_ids)
        self.device_ids.append(device_id)
        return self._row[device_id]

    def remove(self, device_id: str) -> None:
        """Drop a device; later rows move up by one."""
        row = self._row.pop(device_id)
        self.states = np.delete(self.states, row, axis=0)
        self.dt_s = np.delete(self.dt_s, row)
        self.use_mag = np.delete(self.use_mag, row)
        del self.device_ids[row]
        for i in range(row, len(self.device_ids)):
            self._row[self.device_ids[i]] = i

    def row(self, device_id: str) -> int:
        """Row of a device in the stacked arrays."""
        return self._row[device_id]

    def set_dt(self, device_id: str, dt_s: float) -> None:
        """Change one device's sample period (coefficients follow on its next step)."""
        if not dt_s > 0:
            raise ValueError(f"dt_s must be positive, got {dt_s}")
        self.dt_s[self._row[device_id]] = dt_s

    def step(
        self,
        gyr_rad_s: FloatArray,
        acc_m_s2: FloatArray,
        mag_uT: FloatArray | None = None,
        active: NDArray[np.bool_] | None = None,
    ) -> FloatArray:
        """Advance every device by n samples: inputs (N, n, 3) in row order; returns quaternions (N, n, 4).

        `mag_uT=None` runs all devices 6D for this step; rows with `active[i] == False` are left untouched (their
        output rows are NaN), for rounds in which a device sent no packet.
        """
        n_dev = len(self.device_ids)
        gyr = np.ascontiguousarray(gyr_rad_s, dtype=np.float64)
        acc = np.ascontiguousarray(acc_m_s2, dtype=np.float64)
        assert gyr.ndim == 3 and gyr.shape[0] == n_dev and gyr.shape[2] == 3 and acc.shape == gyr.shape
        if mag_uT is None:
            mag = gyr
            use_mag = np.zeros(n_dev, dtype=np.bool_)
        else:
            mag = np.ascontiguousarray(mag_uT, dtype=np.float64)
            assert mag.shape == gyr.shape
            use_mag = self.use_mag
        act = np.ones(n_dev, dtype=np.bool_) if active is None else np.asarray(active, dtype=np.bool_)
        assert act.shape == (n_dev,)
        out = np.full((n_dev, gyr.shape[1], 4), np.nan)
        kernel = K.step_devices if n_dev * gyr.shape[1] >= PARALLEL_MIN_SAMPLES else K.step_devices_serial
        kernel(self.states, self._params, gyr, acc, mag, use_mag, self.dt_s, act, out)
        return out
