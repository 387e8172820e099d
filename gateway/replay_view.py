"""Replay view: open a recording, run a filter over it and scrub through it in viser (seed 004's playback).

    python -m gateway.replay_view ../shared/data/broad/01_undisturbed_slow_rotation_A.mat
    python -m gateway.replay_view var/recordings/session.rigrec --filter mahony --port 8092

    python -m gateway.replay_view logs/rod-1-20260101T000000.000000Z.csv      # a logger file (recording.export)

Input: a BROAD `.mat` trial (`gateway.fusion.broad.load_trial`), a `.rigrec` recording / directory of them
(`gateway.recording`: the first device's IMU packets, with its optical reference if recorded) or a sensor CSV/text
log (`gateway.recording.importers.read_sensor_csv`, e.g. a file of `python -m gateway.recording.export`). The
filter runs once over the whole trial; then a time slider (and Play) drives the 3-D pose: the estimate as a solid
body frame, the reference as a grey ghost. Beside it, in a window around the slider time, uPlots show roll, pitch,
yaw (unwrapped) of both plus the total angle error, and the raw sensor curves as seed 004's desktop program does:
angular rate (°/s), specific force (m/s²) and magnetic field (µT, when recorded), x/y/z each. Binds 127.0.0.1 by
default; the share button is hidden.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from gateway.fusion import broad
from gateway.fusion import quaternion as quat
from gateway.fusion.registry import FILTERS, make_filter
from gateway.recording.format import Record

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ReplayData:
    """Per-sample arrays of one trial for display: time (s), estimate and reference (wxyz, NaN where the
    reference is lost), their Euler angles in degrees (yaw unwrapped) and the total angle error (deg)."""

    name: str
    t_s: FloatArray
    q_est: FloatArray
    q_ref: FloatArray
    euler_est_deg: FloatArray
    euler_ref_deg: FloatArray
    error_deg: FloatArray
    kind: str = "board"  # what the estimate is drawn as: "rod", "hook", or a generic "board" (BROAD trials)
    reference: str = "optical reference"  # where q_ref comes from; "none" when the recording has none
    gyr_deg_s: FloatArray | None = None
    acc_m_s2: FloatArray | None = None
    mag_uT: FloatArray | None = None

    def index(self, t_s: float) -> int:
        """Sample nearest to `t_s`, clamped to the trial."""
        return int(np.clip(np.searchsorted(self.t_s, t_s), 0, len(self.t_s) - 1))

    def window(self, t_s: float, half_width_s: float) -> slice:
        """Samples within ±half_width_s of `t_s`."""
        lo, hi = np.searchsorted(self.t_s, [t_s - half_width_s, t_s + half_width_s])
        return slice(int(lo), int(hi))


def euler_deg(q: FloatArray) -> FloatArray:
    """(N, 3) roll, pitch, yaw in degrees (design.md Z-Y-X), yaw unwrapped; NaN rows stay NaN."""
    out = np.full((q.shape[0], 3), np.nan)
    ok = np.all(np.isfinite(q), axis=1)
    if ok.any():
        e = quat.to_euler(q[ok])
        e[:, 2] = np.unwrap(e[:, 2])
        out[ok] = np.degrees(e)
    return out


def replay_data(trial: broad.Trial, q_est: FloatArray, kind: str = "board", reference: str = "") -> ReplayData:
    """Display arrays from a trial and the estimate of a filter run over it."""
    ok = np.all(np.isfinite(trial.quat_ref), axis=1)
    err = np.full(trial.n, np.nan)
    if ok.any():
        err[ok] = np.degrees(quat.angle_between(q_est[ok], trial.quat_ref[ok]))
    source = reference or ("optical reference" if ok.any() else "none")
    mag = trial.mag_uT if np.isfinite(trial.mag_uT).any() else None
    return ReplayData(trial.name, np.arange(trial.n) / trial.rate_hz, q_est, trial.quat_ref, euler_deg(q_est),
                      euler_deg(trial.quat_ref), err, kind, source, np.degrees(trial.gyr_rad_s), trial.acc_m_s2,
                      mag)  # fmt: skip


SENSORS: tuple[tuple[str, str, str], ...] = (
    ("gyr_deg_s", "angular rate (°/s)", "gyro"),
    ("acc_m_s2", "specific force (m/s²)", "acc"),
    ("mag_uT", "magnetic field (µT)", "mag"),
)
AXIS_COLORS = ("#e53e3e", "#2f855a", "#2b6cb0")


def sensor_columns(data: ReplayData, sensor: str, t_s: float, half_width_s: float,
                   max_points: int = 1500) -> tuple[FloatArray, ...] | None:  # fmt: skip
    """uPlot columns (t, x, y, z) of one raw sensor (`SENSORS` attribute name) around `t_s`, decimated to at most
    about `max_points`; None when the recording has no such sensor."""
    arr: FloatArray | None = getattr(data, sensor)
    if arr is None:
        return None
    w = data.window(t_s, half_width_s)
    step = max(1, (w.stop - w.start) // max_points)
    return tuple(np.ascontiguousarray(c) for c in (data.t_s[w][::step], *(arr[w, k][::step] for k in range(3))))


@dataclass(frozen=True)
class Loaded:
    """A trial to replay, the kind of device it came from and where its reference comes from."""

    trial: broad.Trial
    kind: str
    reference: str


def truth_reference(records: Iterable[Record], kind: str, device_id: str, t0_us: int, rate_hz: float,
                    n: int) -> FloatArray | None:  # fmt: skip
    """(n, 4) per-sample attitude from the simulator's `rig/{kind}/{id}/truth` packets (RodTruth / HookTruth: one
    quaternion per IMU sample, same seq and t0_us as the data packet), placed by device time; None without any."""
    key = f"rig/{kind}/{device_id}/truth"
    q = np.full((n, 4), np.nan)
    for r in records:
        if r.key != key:
            continue
        d = json.loads(r.payload)
        t0, rate = int(d["t0_us"]), float(d["rate_hz"])
        for j, qj in enumerate(d.get("quat_wxyz") or []):
            i = int(round((t0 + j * 1e6 / rate - t0_us) * rate_hz * 1e-6))
            if 0 <= i < n and qj is not None:
                q[i] = qj
    return q if np.isfinite(q).any() else None


def load(path: Path) -> Loaded:
    """A BROAD `.mat` trial, a sensor CSV/text log (seed 004's logger), or the first device of a `.rigrec`
    recording (file or directory): its optical reference if recorded, else the simulator's ground truth."""
    if path.suffix == ".mat":
        return Loaded(broad.load_trial(path), "board", "optical reference")
    if path.suffix in (".csv", ".txt"):
        from gateway.recording.importers import read_sensor_csv

        s = read_sensor_csv(path).stream
        n = s.gyr_rad_s.shape[0]
        mag = s.mag_uT if s.mag_uT is not None else np.full((n, 3), np.nan)
        trial = broad.Trial(path.stem, s.rate_hz, s.gyr_rad_s, s.acc_m_s2, mag, np.full((n, 4), np.nan),
                            np.full((n, 3), np.nan), np.ones(n, dtype=bool))  # fmt: skip
        return Loaded(trial, "board", "none")
    from gateway.recording.format import read_recording
    from gateway.recording.score import recorded_trial

    records = list(read_recording(path))
    rt = recorded_trial(records, name=path.stem)
    trial = rt.trial
    if np.isfinite(trial.quat_ref).any():
        return Loaded(trial, rt.kind, "optical reference")
    truth = truth_reference(records, rt.kind, rt.device_id, rt.t0_us, trial.rate_hz, trial.n)
    if truth is None:
        return Loaded(trial, rt.kind, "none")
    return Loaded(dataclasses.replace(trial, quat_ref=truth), rt.kind, "simulator truth")


KIND_FILTERS = {"hook": "hook"}
"""The filter the gateway runs for a device kind (pipeline.HOOK_FILTER for hooks); others use `default`."""


def run(path: Path, filter_name: str | None, mode: broad.Mode) -> ReplayData:
    """Load, run the filter (None: the one the gateway runs for this device kind), compute display arrays (with a
    progress bar over the stages)."""
    with tqdm(total=3, desc=f"replay {path.name}", unit="step") as bar:
        loaded = load(path)
        trial = loaded.trial
        filter_name = filter_name or KIND_FILTERS.get(loaded.kind, "default")
        bar.update()
        use_mag = mode == "9D" and bool(np.all(np.isfinite(trial.mag_uT)))
        q_est = broad.run_filter(make_filter(filter_name, use_mag=use_mag), trial, "9D" if use_mag else "6D")
        bar.update()
        data = replay_data(trial, q_est, loaded.kind, loaded.reference)
        bar.update()
    return data


CAMERAS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float], float]] = {
    "board": ((0.8, -0.8, 0.6), (0.0, 0.0, 0.0), 1.0),
    "rod": ((-1.5, -4.5, 2.5), (1.5, 0.0, 0.8), 4.0),
    "hook": ((3.0, -3.5, 2.0), (0.0, 0.0, 1.0), 3.0),
}
"""(camera position, look-at point, ground half-size in m) per device model."""
HOOK_ROPE_M = 2.0  # drawn rope of the replayed hook


class DeviceModel:
    """The estimate or the reference drawn as the device it is: a bending rod (view3d.rod_curve) with its tip
    frame, a hook block on its rope (view3d.hook_geometry), or BROAD's board. The reference is a grey ghost:
    offset 0.3 m for rods and hooks (so it never hides under the estimate), translucent or wireframe."""

    def __init__(self, scene: Any, name: str, kind: str, rgb: tuple[int, int, int], ghost: bool,
                 butt_pitch_rad: float) -> None:  # fmt: skip
        self.kind, self.butt = kind, butt_pitch_rad
        offset = (0.0, 0.3, 0.0) if ghost and kind != "board" else (0.0, 0.0, 0.0)
        self.root = scene.add_frame(name, show_axes=False, position=offset)
        self.frame = scene.add_frame(f"{name}/frame", axes_length=0.3 if not ghost else 0.36,
                                     axes_radius=0.012 if not ghost else 0.005)  # fmt: skip
        self.line = None
        if kind == "rod":
            self.line = scene.add_line_segments(f"{name}/rod", np.zeros((1, 2, 3)), rgb, thickness=0.035)
        elif kind == "hook":
            self.line = scene.add_line_segments(f"{name}/rope", np.zeros((1, 2, 3)), rgb, thickness=0.02)
            scene.add_box(f"{name}/frame/block", color=rgb, dimensions=(0.25, 0.18, 0.35), position=(0.0, 0.0, -0.18),
                          wireframe=ghost)  # fmt: skip
        else:
            scene.add_box(f"{name}/frame/body", color=rgb, dimensions=(0.3, 0.18, 0.04) if not ghost else
                          (0.32, 0.2, 0.02), opacity=0.35 if ghost else None)  # fmt: skip

    def pose(self, q: FloatArray) -> None:
        from gateway.view3d import hook_geometry, rod_curve, segments

        q = q / np.linalg.norm(q)
        if self.kind == "rod" and self.line is not None:
            pts = rod_curve(q, self.butt)
            self.line.points = segments(pts)
            self.frame.position = tuple(pts[-1])
        elif self.kind == "hook" and self.line is not None:
            top, hook = hook_geometry(q, HOOK_ROPE_M)
            self.line.points = np.stack([top, hook])[None, :, :]
            self.frame.position = tuple(hook)
        self.frame.wxyz = tuple(q)

    def show(self, visible: bool) -> None:
        self.root.visible = visible


def device_model(scene: Any, name: str, kind: str, rgb: tuple[int, int, int], *, ghost: bool,
                 butt_pitch_rad: float) -> DeviceModel:  # fmt: skip
    return DeviceModel(scene, name, kind, rgb, ghost, butt_pitch_rad)


def serve(data: ReplayData, host: str, port: int, plot_half_width_s: float = 10.0) -> None:  # pragma: no cover
    """viser server with the scrubbing GUI; blocks until Ctrl-C."""
    import viser
    import viser.uplot as uplot

    server = viser.ViserServer(host=host, port=port, label=f"replay {data.name}", verbose=False)
    server.gui.configure_theme(show_share_button=False)
    camera, look_at, ground = CAMERAS.get(data.kind, CAMERAS["board"])
    server.initial_camera.position = camera
    server.initial_camera.look_at = look_at
    server.scene.add_grid("/ground", width=2.0 * ground, height=2.0 * ground, cell_size=0.1 * ground,
                          position=(0.0, 0.0, -0.3 if data.kind == "board" else 0.0))  # fmt: skip
    butt_rad = math.radians(float(np.nan_to_num(data.euler_est_deg[0, 1], nan=30.0)))  # the rod's rest pitch
    est = device_model(server.scene, "/estimate", data.kind, (30, 110, 220), ghost=False, butt_pitch_rad=butt_rad)
    ref = device_model(server.scene, "/reference", data.kind, (170, 170, 170), ghost=True, butt_pitch_rad=butt_rad)
    t_end = float(data.t_s[-1])
    gui = server.gui
    ghost = f"grey: {data.reference}" if np.isfinite(data.q_ref).any() else "no reference in this recording"
    gui.add_markdown(f"**{data.name}** ({data.kind}) — blue: estimate, {ghost} · {t_end:.1f} s")
    slider = gui.add_slider("time (s)", min=0.0, max=t_end, step=0.01, initial_value=0.0)
    playing = gui.add_checkbox("Play", initial_value=False)
    speed = gui.add_dropdown("Speed", options=("0.25x", "0.5x", "1x", "2x", "5x"), initial_value="1x")
    readout = gui.add_markdown("")
    names = ("roll", "pitch", "yaw")
    colors = ("#e53e3e", "#2f855a", "#2b6cb0")
    has_ref = bool(np.isfinite(data.error_deg).any())  # an all-NaN series blanks the whole uPlot: leave it out
    series = [uplot.Series(label="t (s)")]
    for n, c in zip(names, colors, strict=True):
        series.append(uplot.Series(label=f"{n} est", stroke=c, width=1.5))
        if has_ref:
            series.append(uplot.Series(label=f"{n} ref", stroke=c, width=1.0, dash=(4.0, 4.0)))
    if has_ref:
        series.append(uplot.Series(label="error", stroke="#000", width=1.0))

    def plot_data(t_s: float) -> tuple[FloatArray, ...]:
        w = data.window(t_s, plot_half_width_s)
        step = max(1, (w.stop - w.start) // 1500)  # keep the browser fast
        cols = [data.t_s[w][::step]]
        for k in range(3):
            cols.append(data.euler_est_deg[w, k][::step])
            if has_ref:
                cols.append(data.euler_ref_deg[w, k][::step])
        if has_ref:
            cols.append(data.error_deg[w][::step])
        return tuple(np.ascontiguousarray(c) for c in cols)

    plot = gui.add_uplot(plot_data(0.0), tuple(series), title="attitude (deg) around the slider time",
                         scales={"x": uplot.Scale(time=False, auto=True)}, aspect=1.4)  # fmt: skip
    raw_plots = []
    for attr, title, short in SENSORS:
        cols = sensor_columns(data, attr, 0.0, plot_half_width_s)
        if cols is None:
            continue
        axes = tuple(uplot.Series(label=f"{short} {a}", stroke=c, width=1.0) for a, c in zip("xyz", AXIS_COLORS,
                                                                                                 strict=True))
        raw_plots.append((attr, gui.add_uplot(cols, (uplot.Series(label="t (s)"), *axes), title=title,
                                               scales={"x": uplot.Scale(time=False, auto=True)}, aspect=2.0)))

    def show(t_s: float) -> None:
        i = data.index(t_s)
        est.pose(data.q_est[i])
        ok = bool(np.all(np.isfinite(data.q_ref[i])))
        ref.show(ok)
        if ok:
            ref.pose(data.q_ref[i])
        e = data.euler_est_deg[i]
        err = data.error_deg[i]
        readout.content = (f"t = {data.t_s[i]:.2f} s · roll {e[0]:.1f}° pitch {e[1]:.1f}° yaw {e[2]:.1f}°"
                           + ("" if math.isnan(err) else f" · error {err:.2f}°"))  # fmt: skip
        plot.data = plot_data(t_s)
        for attr, raw in raw_plots:
            cols = sensor_columns(data, attr, t_s, plot_half_width_s)
            if cols is not None:
                raw.data = cols

    @slider.on_update
    def _(_: object) -> None:
        show(slider.value)

    show(0.0)
    print(f"replay view on http://{host}:{server.get_port()} (Ctrl-C to stop)")
    stop = threading.Event()
    try:
        last = time.monotonic()
        while not stop.wait(0.05):
            now = time.monotonic()
            if playing.value:
                t = slider.value + (now - last) * float(speed.value.rstrip("x"))
                slider.value = t if t <= t_end else 0.0  # type: ignore[misc]
            last = now
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gateway.replay_view", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("path", type=Path, help="BROAD .mat file, .rigrec recording (file or directory) or CSV/text log")
    p.add_argument("--filter", default=None, choices=sorted(FILTERS),
                   help="attitude filter (default: the gateway's for the device kind: hook for hooks, else default)")
    p.add_argument("--mode", choices=["6D", "9D"], default="9D", help="use the magnetometer (9D) or not (default 9D)")
    p.add_argument("--host", default="127.0.0.1", help="viser bind address (default: 127.0.0.1)")
    p.add_argument("--port", type=int, default=8090, help="viser port (default: 8090; the next free one if taken)")
    p.add_argument("--window", type=float, default=10.0, help="plot half-width around the slider, s (default: 10)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not args.path.exists():
        print(f"no such file: {args.path}")
        return 2
    data = run(args.path, args.filter, args.mode)
    serve(data, args.host, args.port, args.window)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
