"""Read views of the live state shared by REST and the dashboard stream: a device's card (`device_view`) and the
plotted values of an output (`plot_point`). Called on the event loop between batches (a batch never yields), so
they see whole batches; they never change anything.
"""

from __future__ import annotations

import math
import operator
import time
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING, Any, Final, overload

import numpy as np

from gateway import schemas
from gateway.fusion.base import FloatArray

if TYPE_CHECKING:  # the hub imports this module, and the runner imports the hub
    from gateway.ingest.runner import GatewayService


def device_view(service: GatewayService, device_id: str, *, detail: bool) -> dict[str, Any]:
    """Live state of one device: presence, last packet age, stream counters, attitude / readings."""
    pl = service.pipeline
    kind = pl.kinds[device_id]
    stream = service.counters.devices.get(device_id)
    mono = time.monotonic()
    out: dict[str, Any] = {
        "device_id": device_id,
        "kind": kind,
        "online": service.presence.online(device_id),
        "last_packet_age_s": None if stream is None or stream.last_arrival_s is None else mono - stream.last_arrival_s,
        "loss_fraction": 0.0 if stream is None else stream.loss_fraction(),
        "filter": pl.effective(kind, device_id)[0] if kind != "ball" else None,
        "active_alarms": [a.type for a in pl.engine.active(device_id)],
    }
    dev = pl.devices.get(device_id)
    if dev is not None:
        out["attitude"] = {
            "quat_wxyz": [float(x) for x in dev.quat], "roll_rad": float(dev.euler[0]),
            "pitch_rad": float(dev.euler[1]), "yaw_rad": float(dev.euler[2]), "yaw_unwrapped_rad": dev.yaw_unwrapped,
            "t_us": dev.t_us, "seq": dev.seq,
        }  # fmt: skip
        if dev.swing is not None:
            out["swing"] = dev.swing.model_dump()
        if dev.height is not None:
            out["height"] = dev.height.model_dump()
        if kind == "rod":
            out["auto_reel"] = pl.auto_reel.get(device_id, False)
    if kind != "ball":  # an IMU calibration applied before fusion (`python -m gateway.calibrate`, the hook's twist)
        entry = pl.device_settings.get(device_id)
        out["imu_calibration"] = entry is not None and entry[1].calibration is not None
    feed_view = getattr(pl.handlers.get(kind), "feed_view", None)  # a hook's crane feed (docs/protocol.md 3.7)
    if feed_view is not None:
        out["crane_feed"] = feed_view(device_id, time.time())
    if device_id in pl.env:
        out["readings"] = pl.env[device_id].model_dump(exclude={"profile"} if not detail else set())
    if device_id in pl.reel:
        out["reel"] = pl.reel[device_id][0].model_dump()
    if detail:
        out["gyro_bias_rad_s"] = pl.bias_rad_s(device_id)
        filt = dev.filt if dev is not None else None
        compass = getattr(filt, "compass", None)
        if isinstance(compass, str):  # the hook filter's magnetometer: tested, trusted or dropped (docs/fusion.md)
            out["compass"] = compass
            out["compass_dropped_s"] = getattr(filt, "compass_dropped_s", None)
            out["start_redone_s"] = getattr(filt, "start_redone_s", None)  # not told its rope, or told one the swing
            # disagreed with: started again told the length it found
            out["start_pending"] = bool(getattr(filt, "start_pending", False))  # ... still may: its alarms wait
            # the warm-up's mean x/y force and whether the start took it for the accelerometer's offset (a hook held
            # aside at start would be misread as one up to `max_warmup_acc_bias_m_s2`: docs/fusion.md)
            force = getattr(filt, "start_force_m_s2", None)
            out["start_force_m_s2"] = None if force is None else list(force)
            out["start_force_is_offset"] = bool(getattr(filt, "start_force_is_offset", False))
        if stream is not None:
            t = stream.main()
            out["stream"] = {"ok": t.ok, "lost": t.lost, "duplicates": t.duplicates, "reordered": t.reordered,
                             "reboots": t.reboots, "rejected": dict(stream.rejected),
                             "filter_restarts": dict(stream.filter_restarts)}  # fmt: skip
            if "imu" in stream.trackers:  # the IMU rate as declared and as its t0_us show (docs/protocol.md 3.1)
                r = stream.rate
                out["stream"]["sample_rate"] = {"declared_hz": r.declared_hz, "measured_hz": r.measured_hz,
                                                "used_hz": r.used_hz or r.declared_hz, "evidence_s": r.evidence_s}
    return out


PlotPoint = tuple[str, float, dict[str, float]]
"""(device id, wall time s, plotted values in degrees): one point of the dashboard's series."""


_PLOT_SOURCES: Final = {
    schemas.Attitude: (("roll_deg", "roll_rad"), ("pitch_deg", "pitch_rad"), ("yaw_deg", "yaw_unwrapped_rad")),
    schemas.Swing: (("swing_deg", "swing_angle_rad"), ("direction_deg", "swing_direction_rad"),
                    ("torsion_deg", "torsion_rad")),
}
"""Per plotted output type, (plotted field in degrees, the model's attribute in radians): the one table that turns hub
outputs into the dashboard's series, for `plot_point` and `PlotBatch.columns` alike."""

PLOT_FIELDS: Final = tuple(name for pairs in _PLOT_SOURCES.values() for name, _ in pairs)
"""Every value a plot point can carry: an Attitude's three, then a Swing's three (`PlotBatch.columns`)."""


def _wall_s(model: schemas.Attitude | schemas.Swing) -> float:
    """The output's wall time, s (now if it has none)."""
    return (model.wall_t_us or time.time() * 1e6) / 1e6


def plot_point(model: schemas.WireModel) -> PlotPoint | None:
    """(device id, wall time s, plotted values in degrees) of an Attitude or Swing output, else None (`_PLOT_SOURCES`;
    the history and the live stream plot these)."""
    pairs = _PLOT_SOURCES.get(type(model))
    if pairs is None or not isinstance(model, schemas.Attitude | schemas.Swing):
        return None
    return model.device_id, _wall_s(model), {name: math.degrees(getattr(model, attr)) for name, attr in pairs}


def plot_points(models: list[schemas.WireModel]) -> list[PlotPoint]:
    """`plot_point` of each Attitude or Swing of a batch, in order (the hub computes them once for every sink)."""
    return [pt for m in models if (pt := plot_point(m)) is not None]


class PlotBatch(Sequence[PlotPoint]):
    """The dashboard points of one batch's published attitudes and then swings, for every plot sink: a sequence of
    their `plot_point`s, made on first use (the live stream reads them only while someone watches it), and the same
    values as columns (`columns`), which the history folds in with a few numpy calls per batch instead of a dict
    and a Python fold per point."""

    def __init__(self, attitudes: Sequence[schemas.Attitude], swings: Sequence[schemas.Swing]) -> None:
        self.attitudes, self.swings = list(attitudes), list(swings)
        self._points: list[PlotPoint] | None = None

    def points(self) -> list[PlotPoint]:
        """`plot_points` of the attitudes and swings, in that order (made once)."""
        if self._points is None:
            self._points = plot_points([*self.attitudes, *self.swings])
        return self._points

    @overload
    def __getitem__(self, index: int) -> PlotPoint: ...

    @overload
    def __getitem__(self, index: slice) -> list[PlotPoint]: ...

    def __getitem__(self, index: int | slice) -> PlotPoint | list[PlotPoint]:
        return self.points()[index]

    def __len__(self) -> int:
        return len(self.attitudes) + len(self.swings)

    def __iter__(self) -> Iterator[PlotPoint]:
        return iter(self.points())

    def __eq__(self, other: object) -> bool:
        if isinstance(other, PlotBatch):
            other = other.points()
        return isinstance(other, list) and self.points() == other

    __hash__ = None  # type: ignore[assignment]

    def columns(self) -> tuple[list[str], list[float], FloatArray]:
        """(device ids, wall times s, values): point k of the sequence is device `ids[k]` at `t_s[k]` with
        `values[k]` (n, len(PLOT_FIELDS)) in degrees, NaN where its output has no such value; the same floats as
        its `plot_point` (np.degrees and math.degrees multiply by the same constant)."""
        atts, swings = self.attitudes, self.swings
        ids = [m.device_id for m in atts] + [m.device_id for m in swings]
        t_s = [_wall_s(m) for m in atts] + [_wall_s(m) for m in swings]
        values = np.full((len(ids), len(PLOT_FIELDS)), np.nan)
        for start, models, kind in ((0, atts, schemas.Attitude), (len(atts), swings, schemas.Swing)):
            if models:
                pairs = _PLOT_SOURCES[kind]
                col = PLOT_FIELDS.index(pairs[0][0])
                read = operator.attrgetter(*(attr for _, attr in pairs))
                values[start : start + len(models), col : col + len(pairs)] = np.degrees(
                    np.array([read(m) for m in models], dtype=np.float64))  # fmt: skip
        return ids, t_s, values
