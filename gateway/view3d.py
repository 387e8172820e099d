"""viser 3-D view of the live rig: rods as bending rods with their tip frame, hooks as rope + hook.

Geometry is pure (`rod_curve`, `hook_geometry`, `raw_attitude`); `View3D` owns a `viser.ViserServer` bound to
`Settings.viser_host:viser_port` (127.0.0.1 by default; viser takes the next free port if that one is busy) and
a 20 Hz update thread. `python -m gateway` starts it with the gateway (`start_view3d`); in-process apps start it on
the first `GET /view3d` (the dashboard's link), so tests that never open it pay nothing; the lifespan stops it.

Inputs: fused attitude and swing from the hub (listener on the ingest task, stores the latest values only), raw
IMU and ground truth (`rig/{kind}/{id}/truth`) from bus subscriptions whose callbacks only keep the latest bytes.
Scene frames are ENU (viser's z is up, as ours). Quaternions are wxyz body->earth, which is what viser takes.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from fastapi import APIRouter, Request
from fastapi.responses import RedirectResponse
from numpy.typing import NDArray

from gateway import schemas
from gateway.config import Settings
from gateway.fusion import quaternion as quat
from gateway.ingest.runner import GatewayService

log = logging.getLogger("gateway.view3d")
FloatArray = NDArray[np.float64]
router = APIRouter()

FUSED_RGB = (30, 110, 220)
RAW_RGB = (230, 140, 20)
TRUTH_RGB = (160, 160, 160)
HOOK_ROPE_M = 4.0  # drawn rope length (the real one is unknown to the gateway); fits the default camera


# -- pure geometry ------------------------------------------------------------------------------------------------


def rod_curve(tip_wxyz: FloatArray, butt_pitch_rad: float, length_m: float = 3.0, n: int = 16) -> FloatArray:
    """Points (n, 3) of a rod of `length_m` as a constant-curvature arc from the butt (origin) to the tip.

    The arc lies in the vertical plane of the tip's heading: its elevation goes linearly from `butt_pitch_rad`
    at the butt to the tip pitch θt at the tip (the tip tangent is body x, design.md), i.e. for s ∈ [0, L]
    θ(s) = θb + (θt − θb)·s/L, horizontal distance h(s) = ∫cos θ, height z(s) = ∫sin θ (closed form below).
    A bite pulls the tip below the butt's elevation, so the drawn rod bends.
    """
    x_tip = quat.rotate(tip_wxyz, np.array([1.0, 0.0, 0.0]))
    theta_t = math.asin(max(-1.0, min(1.0, float(x_tip[2]))))
    heading = math.atan2(float(x_tip[1]), float(x_tip[0])) if abs(x_tip[2]) < 1.0 - 1e-9 else 0.0
    s = np.linspace(0.0, length_m, n)
    k = (theta_t - butt_pitch_rad) / length_m  # curvature, rad/m
    if abs(k) < 1e-9:
        h, z = s * math.cos(theta_t), s * math.sin(theta_t)
    else:
        h = (np.sin(butt_pitch_rad + k * s) - math.sin(butt_pitch_rad)) / k
        z = (math.cos(butt_pitch_rad) - np.cos(butt_pitch_rad + k * s)) / k
    out: FloatArray = np.stack([h * math.cos(heading), h * math.sin(heading), z], axis=-1)
    return out


def hook_geometry(wxyz: FloatArray, rope_m: float = 8.0) -> tuple[FloatArray, FloatArray]:
    """(boom tip, hook position), m. The boom tip is at (0, 0, rope_m); body z points up the rope (design.md), so
    the hook hangs at boom_tip − rope_m · R(q)·ẑ. Swing tilts the rope; torsion turns the hook about it."""
    top = np.array([0.0, 0.0, rope_m])
    up_rope = quat.rotate(wxyz, np.array([0.0, 0.0, 1.0]))
    hook: FloatArray = top - rope_m * up_rope
    return top, hook


def raw_attitude(acc_m_s2: FloatArray, mag_uT: FloatArray | None) -> FloatArray:
    """Attitude from one sample's sensors alone, no gyro: acc (+ mag) at rest, seed 000 eq. 17-18 / seed 004."""
    if mag_uT is None or not np.all(np.isfinite(mag_uT)) or np.linalg.norm(mag_uT) < 1e-6:
        return quat.from_acc(acc_m_s2)
    return quat.from_acc_mag(acc_m_s2, mag_uT)


def segments(points: FloatArray) -> FloatArray:
    """Polyline (n, 3) -> line segments (n-1, 2, 3) for viser's add_line_segments."""
    return np.stack([points[:-1], points[1:]], axis=1)


# -- live state ---------------------------------------------------------------------------------------------------


@dataclass
class DeviceView:
    """Latest values of one device for the scene."""

    kind: str
    fused: FloatArray
    butt_pitch_rad: float = math.nan
    swing: dict[str, float] | None = None


class View3D:
    """The viser server and its scene; `attach` feeds it from a running GatewayService."""

    def __init__(self, settings: Settings, rate_hz: float = 20.0) -> None:
        import viser

        self.server = viser.ViserServer(host=settings.viser_host, port=settings.viser_port, label="rig-gateway 3D",
                                        verbose=False)  # fmt: skip
        self.server.gui.configure_theme(show_share_button=False, dark_mode=False)
        self.rate_hz = rate_hz
        self.devices: dict[str, DeviceView] = {}
        self._raw: dict[str, bytes] = {}
        self._truth: dict[str, bytes] = {}
        self._nodes: dict[str, dict[str, Any]] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.updates = 0
        self.server.initial_camera.position = (1.0, -4.5, 2.2)
        self.server.initial_camera.look_at = (1.5, 0.5, 1.0)
        s = self.server.scene
        s.add_grid("/ground", width=20.0, height=20.0, cell_size=1.0, plane="xy")
        s.add_frame("/world", axes_length=0.5, axes_radius=0.01)
        gui = self.server.gui
        gui.add_markdown("**rig-gateway 3D** — blue: fused, orange: raw (acc+mag only), grey: ground truth")
        self.pick = gui.add_dropdown("Device", options=("(none yet)",), initial_value="(none yet)")
        self.show_fused = gui.add_checkbox("Show fused", initial_value=True)
        self.show_raw = gui.add_checkbox("Show raw", initial_value=False)
        self.show_truth = gui.add_checkbox("Show ground truth", initial_value=True)
        self.status = gui.add_markdown("waiting for data")

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    # callbacks: hub (event loop) and bus (zenoh threads) only store values
    def on_hub(self, topic: str, model: schemas.WireModel) -> None:
        if isinstance(model, schemas.Attitude):
            d = self.devices.get(model.device_id)
            q = np.asarray(model.quat_wxyz, dtype=np.float64)
            if d is None:
                self.devices[model.device_id] = DeviceView(model.kind, q, butt_pitch_rad=model.pitch_rad)
            else:
                d.fused = q
                if model.kind == "rod":  # butt elevation follows the tip slowly (rest pitch, ~5 s)
                    b = d.butt_pitch_rad
                    d.butt_pitch_rad = model.pitch_rad if math.isnan(b) else b + 0.004 * (model.pitch_rad - b)
        elif isinstance(model, schemas.Swing) and model.device_id in self.devices:
            self.devices[model.device_id].swing = {
                "swing_deg": math.degrees(model.swing_angle_rad), "torsion_deg": math.degrees(model.torsion_rad),
                "direction_deg": math.degrees(model.swing_direction_rad),
            }  # fmt: skip

    def on_raw(self, key: str, payload: bytes) -> None:
        self._keep(self._raw, key, payload)

    def on_truth(self, key: str, payload: bytes) -> None:
        self._keep(self._truth, key, payload)

    def _keep(self, store: dict[str, bytes], key: str, payload: bytes) -> None:
        """Latest payload per device, only for devices with a fused attitude (anyone may publish on these keys)."""
        device_id = key.rsplit("/", 2)[1]
        if device_id in self.devices:
            store[device_id] = payload

    def attach(self, service: GatewayService) -> None:
        service.hub.listeners.append(self.on_hub)
        service.bus.subscribe(schemas.SEL_IMU, self.on_raw)
        service.bus.subscribe(schemas.SEL_TRUTH, self.on_truth)

    # scene updates (own thread; viser handles may be set from any thread)
    def _latest(self, store: dict[str, bytes], device_id: str, field: str) -> FloatArray | None:
        raw = store.get(device_id)
        if raw is None:
            return None
        try:
            rows = json.loads(raw).get(field)
            return None if not rows else np.asarray(rows[-1], dtype=np.float64)
        except (ValueError, TypeError, AttributeError):
            return None

    def _node_set(self, device_id: str, kind: str) -> dict[str, Any]:
        nodes = self._nodes.get(device_id)
        if nodes is not None:
            return nodes
        s, base = self.server.scene, f"/dev/{device_id}"
        nodes = {}
        for layer, rgb in (("fused", FUSED_RGB), ("raw", RAW_RGB), ("truth", TRUTH_RGB)):
            pts = np.zeros((2, 2, 3))
            nodes[f"{layer}_line"] = s.add_line_segments(f"{base}/{layer}/line", pts, rgb, thickness=0.04)
            nodes[f"{layer}_frame"] = s.add_frame(f"{base}/{layer}/frame", axes_length=0.4, axes_radius=0.02)
            if kind == "hook":
                nodes[f"{layer}_hook"] = s.add_box(f"{base}/{layer}/frame/hook", color=rgb,
                                                   dimensions=(0.6, 0.15, 0.3), position=(0.15, 0.0, -0.2))  # fmt: skip
        nodes["label"] = s.add_label(f"{base}/label", device_id, position=(0.0, 0.0, 0.3))
        self._nodes[device_id] = nodes
        return nodes

    def _place(self, nodes: dict[str, Any], layer: str, kind: str, q: FloatArray | None, d: DeviceView,
               visible: bool) -> None:  # fmt: skip
        show = visible and q is not None and bool(np.all(np.isfinite(q)))
        for suffix in ("line", "frame", "hook"):
            if f"{layer}_{suffix}" in nodes:
                nodes[f"{layer}_{suffix}"].visible = show
        if not show or q is None:
            return
        q = q / np.linalg.norm(q)
        if kind == "rod":
            butt = d.butt_pitch_rad if math.isfinite(d.butt_pitch_rad) else 0.5
            pts = rod_curve(q, butt)
            nodes[f"{layer}_line"].points = segments(pts)
            tip = pts[-1]
        else:
            top, tip = hook_geometry(q, HOOK_ROPE_M)
            nodes[f"{layer}_line"].points = np.stack([top, tip])[None, :, :]
        nodes[f"{layer}_frame"].position = tuple(tip)
        nodes[f"{layer}_frame"].wxyz = tuple(q)

    def step(self) -> None:
        """One scene update: options of the device picker, then the picked device's three layers."""
        ids = sorted(self.devices)
        if ids and tuple(ids) != tuple(self.pick.options):
            current = self.pick.value
            self.pick.options = tuple(ids)
            self.pick.value = current if current in ids else ids[0]  # type: ignore[misc]
        for device_id, d in list(self.devices.items()):
            nodes = self._node_set(device_id, d.kind)
            on = device_id == self.pick.value
            nodes["label"].visible = on
            raw_q = None
            acc = self._latest(self._raw, device_id, "acc_m_s2")
            if on and self.show_raw.value and acc is not None and np.linalg.norm(acc) > 1e-6:
                raw_q = raw_attitude(acc, self._latest(self._raw, device_id, "mag_uT"))
            truth = self._latest(self._truth, device_id, "quat_wxyz") if on else None
            self._place(nodes, "fused", d.kind, d.fused, d, on and self.show_fused.value)
            self._place(nodes, "raw", d.kind, raw_q, d, on and self.show_raw.value)
            self._place(nodes, "truth", d.kind, truth, d, on and self.show_truth.value)
        picked = self.devices.get(self.pick.value)
        if picked is not None:
            e = np.degrees(quat.to_euler(picked.fused))
            text = f"**{self.pick.value}** ({picked.kind}) roll {e[0]:.1f}° pitch {e[1]:.1f}° yaw {e[2]:.1f}°"
            if picked.swing:
                sw = picked.swing
                text += f"  \nswing {sw['swing_deg']:.1f}° torsion {sw['torsion_deg']:.1f}°"
            self.status.content = text
        self.updates += 1

    def _loop(self) -> None:
        period = 1.0 / self.rate_hz
        while not self._stop.wait(period):
            try:
                self.step()
            except Exception:
                log.exception("3-D view update failed")

    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop, name="view3d", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        with contextlib.suppress(Exception):
            self.server.stop()


_lock = threading.Lock()


def ensure_view3d(app: Any) -> View3D:
    """The app's View3D, started on first use (thread-safe)."""
    with _lock:
        view: View3D | None = getattr(app.state, "view3d", None)
        if view is None:
            service: GatewayService = app.state.service
            view = View3D(service.settings)
            view.attach(service)
            view.start()
            app.state.view3d = view
            log.info("3-D view on http://%s:%d", service.settings.viser_host, view.port)
        return view


async def start_view3d(app: Any) -> View3D:
    """Start the 3-D view with the gateway: the viser server is built off the event loop (importing and starting
    it takes a second or two), then attached to the service on the loop."""
    service: GatewayService = app.state.service
    view = await asyncio.to_thread(View3D, service.settings)
    with _lock:
        if getattr(app.state, "view3d", None) is not None:  # a `GET /view3d` was faster
            view.stop()
            existing: View3D = app.state.view3d
            return existing
        view.attach(service)
        view.start()
        app.state.view3d = view
    return view


def stop_view3d(app: Any) -> None:
    """Stop the 3-D view if it was started (lifespan shutdown)."""
    view: View3D | None = getattr(app.state, "view3d", None)
    if view is not None:
        view.stop()
        app.state.view3d = None


@router.get("/view3d", include_in_schema=False)
def open_view3d(request: Request) -> RedirectResponse:
    """Start the viser server if needed and redirect to it (same host name the browser used)."""
    view = ensure_view3d(request.app)
    host = request.url.hostname or "127.0.0.1"
    return RedirectResponse(f"http://{host}:{view.port}/", status_code=307)


@router.get("/api/view3d", tags=["health"])
def view3d_info(request: Request) -> dict[str, Any]:
    """Whether the 3-D view runs, its port and scene updates so far."""
    view: View3D | None = getattr(request.app.state, "view3d", None)
    if view is None:
        return {"running": False}
    return {"running": True, "port": view.port, "updates": view.updates, "devices": sorted(view.devices),
            "clients": len(view.server.get_clients()), "t_s": time.time()}  # fmt: skip
