"""Step many devices' default filters together: stacked state (N, ...) through one numba call per packet round.

Each device keeps its own sample period and 6D/9D flag; devices join and leave at any time. The kernel runs the very
code path of `DefaultFilter.update_block` per device, so results equal the single-device filter (tested to 1e-9).
"""

from __future__ import annotations

import os
from typing import Any

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
    """N default filters in rows of one context array (N, N_CTX) (`_default_kernels.X_*`: state, settings,
    coefficients, scratch, period, 6D/9D flag); rows follow `device_ids` (order of joining, compacted on removal)."""

    def __init__(self, settings: DefaultSettings | None = None) -> None:
        self.settings = settings or DefaultSettings()
        self._params = self.settings.to_array()
        self.device_ids: list[str] = []
        self._row: dict[str, int] = {}
        self._ctx = np.empty((0, K.N_CTX))
        self._all_active = True  # every row's X_ACTIVE is 1 (so a step without a mask writes nothing)
        self._parallel, self._serial = K.rows_kernels()
        self._fast = True  # inputs so far were C-contiguous float64 (no conversion)

    def __len__(self) -> int:
        return len(self.device_ids)

    @property
    def states(self) -> FloatArray:
        """Kernel states (N, N_STATE): a view, writes go to the filters."""
        return self._ctx[:, K.X_STATE : K.X_STATE + K.N_STATE]

    @property
    def dt_s(self) -> FloatArray:
        """Sample period of each row (N,), read-only copy (`set_dt` changes one)."""
        return self._ctx[:, K.X_DT].copy()

    @property
    def use_mag(self) -> NDArray[np.bool_]:
        """9D flag of each row (N,)."""
        return np.asarray(self._ctx[:, K.X_USE_MAG] != 0.0, dtype=np.bool_)

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
        row = K.new_context(self._params, initial_state(self._params, acc_m_s2, mag_uT if use_mag else None))
        row[K.X_DT] = float(dt_s)
        row[K.X_USE_MAG] = float(bool(use_mag))
        self._ctx = np.vstack([self._ctx, row[None]])
        self._all_active = False
        self._row[device_id] = len(self.device_ids)
        self.device_ids.append(device_id)
        return self._row[device_id]

    def remove(self, device_id: str) -> None:
        """Drop a device; later rows move up by one."""
        row = self._row.pop(device_id)
        self._ctx = np.delete(self._ctx, row, axis=0)
        del self.device_ids[row]
        for i in range(row, len(self.device_ids)):
            self._row[self.device_ids[i]] = i

    def row(self, device_id: str) -> int:
        """Row of a device in the stacked arrays."""
        return self._row[device_id]

    def rows(self, device_ids: list[str]) -> list[int]:
        """Rows of many devices, in their order."""
        return [self._row[d] for d in device_ids]

    def set_dt(self, device_id: str, dt_s: float) -> None:
        """Change one device's sample period (coefficients follow on its next step)."""
        if not dt_s > 0:
            raise ValueError(f"dt_s must be positive, got {dt_s}")
        self._ctx[self._row[device_id], K.X_DT] = dt_s

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
        if active is not None:
            act = np.asarray(active, dtype=np.bool_)
            if act.shape != (len(self.device_ids),):
                raise ValueError(f"active must be ({len(self.device_ids)},), got {act.shape}")
            self._ctx[:, K.X_ACTIVE] = act
            self._all_active = False
        elif not self._all_active:
            self._ctx[:, K.X_ACTIVE] = 1.0
            self._all_active = True
        mag_on = mag_uT is not None
        mag = mag_uT if mag_uT is not None else gyr_rad_s
        if self._fast:
            try:
                out = np.empty((len(gyr_rad_s), len(gyr_rad_s[0]) if len(gyr_rad_s) else 0, 4))
                self._kernel(out.shape[1])(self._ctx, gyr_rad_s, acc_m_s2, mag, mag_on, out)
                return out
            except TypeError:  # convert from now on (numba's failed type match costs ~80 µs per call)
                self._fast = False
        gyr = np.ascontiguousarray(gyr_rad_s, dtype=np.float64)
        acc = np.ascontiguousarray(acc_m_s2, dtype=np.float64)
        mag = np.ascontiguousarray(mag, dtype=np.float64) if mag_on else gyr
        if gyr.ndim != 3 or acc.ndim != 3 or mag.ndim != 3:
            raise ValueError("gyr, acc and mag must be (N, n, 3) arrays")
        out = np.empty((gyr.shape[0], gyr.shape[1], 4))
        self._kernel(out.shape[1])(self._ctx, gyr, acc, mag, mag_on, out)
        return out

    def step_rows(self, rows: NDArray[np.int64], gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray
                  ) -> FloatArray:  # fmt: skip
        """Advance only the devices in `rows` (k,) by n samples: inputs (k, n, 3) float64, C-contiguous, in that
        order (`mag_uT` read where a row is 9D); returns their quaternions (k, n, 4). The other rows are neither
        stepped nor copied, so a block length few devices share (after lost packets) costs those few, not N."""
        sub = self._ctx[rows]
        sub[:, K.X_ACTIVE] = 1.0
        out = np.empty((sub.shape[0], gyr_rad_s.shape[1], 4))
        self._kernel(out.shape[1], sub.shape[0])(sub, gyr_rad_s, acc_m_s2, mag_uT, True, out)
        self._ctx[rows] = sub
        self._all_active = False
        return out

    def _kernel(self, n_samples: int, n_rows: int | None = None) -> Any:
        """The parallel kernel for `n_rows` (default: every device) × `n_samples` of work, else the serial one."""
        rows = len(self.device_ids) if n_rows is None else n_rows
        return self._parallel if rows * n_samples >= PARALLEL_MIN_SAMPLES else self._serial
