"""viser 3-D view of the live rig: rods as bending rods with their tip frame, hooks as rope + hook.

Geometry is pure (`rod_curve`, `hook_geometry`, `raw_attitude`); `View3D` owns a `viser.ViserServer` bound to
`Settings.viser_host:viser_port` (127.0.0.1 by default; viser takes the next free port if that one is busy) and
a 20 Hz update thread. `python -m gateway` starts it with the gateway (`start_view3d`); in-process apps start it on
the first `GET /view3d` (the dashboard's link), so tests that never open it pay nothing; the lifespan stops it.

Inputs: fused attitude and swing from the hub, and the raw IMU packets ingest decoded (hub sinks on the ingest task
that keep the latest values of devices with a fused attitude only); ground truth (`rig/{kind}/{id}/truth`, which
only simulators publish and ingest does not read) from a bus subscription whose callback keeps the latest bytes.
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
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from fastapi import APIRouter, Request
from fastapi.responses import RedirectResponse
from numpy.typing import NDArray

from gateway import schemas
from gateway.config import HookThresholds, Settings
from gateway.fusion import quaternion as quat
from gateway.hub import listens_to
from gateway.ingest.runner import GatewayService

log = logging.getLogger("gateway.view3d")
FloatArray = NDArray[np.float64]
router = APIRouter()

FUSED_RGB = (30, 110, 220)
RAW_RGB = (230, 140, 20)
TRUTH_RGB = (160, 160, 160)
HOOK_ROPE_M = 4.0  # drawn rope length (the real one is unknown to the gateway); fits the default camera
WATER_Z_M = -1.2  # water surface below the rod butt
HOOK_LIFT_M = 2.0  # the hook scene stands this much higher, so the load hangs above the ground grid
IMU_HEIGHT_M = 1.0  # a plain IMU's frame is drawn this high above its slot
SLOT_M = 6.0  # devices side by side along y, this far apart
GHOST_OFFSET_M = (0.0, 0.35, 0.0)  # ground truth drawn beside the estimate, so it never hides under it
ALL = "(all devices)"
LEGEND = """**rig-gateway 3D**  \n<span style="color:#1e6edc">■</span> fused estimate ·
<span style="color:#e68c14">■</span> raw (acc + mag only) · <span style="color:#a0a0a0">■</span> ground truth
(simulator, drawn 0.35 m aside, hook as wireframe)  \nrod: blue plane = water, dark line to a red bait · hook:
boom, rope, hook block and load; cone = swing warning limit, magenta arc = torsion φ"""


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


def fishing_line(tip: FloatArray, water_z_m: float, reach_m: float = 2.0, depth_m: float = 0.8) -> FloatArray:
    """Points (3, 3) of the line: rod tip -> where it enters the water, `reach_m` further out along the tip's
    horizontal direction from the butt (origin) -> the bait, `depth_m` below the surface."""
    out_dir = np.array([tip[0], tip[1], 0.0])
    n = float(np.linalg.norm(out_dir))
    out_dir = out_dir / n if n > 1e-9 else np.array([1.0, 0.0, 0.0])
    entry = np.array([tip[0], tip[1], water_z_m]) + reach_m * out_dir
    bait = entry + np.array([0.3 * out_dir[0], 0.3 * out_dir[1], -depth_m])
    return np.stack([np.asarray(tip, dtype=np.float64), entry, bait])


def cone_mesh(
    apex: FloatArray, length_m: float, half_angle_rad: float, n: int = 32
) -> tuple[FloatArray, NDArray[np.int32]]:
    """Open cone hanging from `apex` (the swing limit: every rope direction within `half_angle_rad` of the
    vertical): vertices (n+1, 3), apex first, base circle of radius L·sin α at depth L·cos α; faces (n, 3)."""
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    r, h = length_m * math.sin(half_angle_rad), length_m * math.cos(half_angle_rad)
    ring = np.stack([apex[0] + r * np.cos(a), apex[1] + r * np.sin(a), np.full(n, apex[2] - h)], axis=-1)
    verts: FloatArray = np.vstack([np.asarray(apex, dtype=np.float64)[None, :], ring])
    faces = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)], dtype=np.int32)
    return verts, faces


def torsion_arc(center: FloatArray, phi_rad: float, radius_m: float = 0.6, n: int = 24) -> FloatArray:
    """Segments (m, 2, 3) of a horizontal arc around `center` from the rest direction (x) to the torsion φ, with an
    arrow head at φ: it shows how far and which way the hook has turned about the rope."""
    a = np.linspace(0.0, phi_rad, max(2, n))
    arc = np.stack([center[0] + radius_m * np.cos(a), center[1] + radius_m * np.sin(a), np.full(a.size, center[2])], -1)
    segs = [segments(arc)]
    if abs(phi_rad) > 1e-3:  # head: two strokes back along the arc's tangent, opening outwards and inwards
        end, sign = arc[-1], math.copysign(1.0, phi_rad)
        tangent = sign * np.array([-math.sin(phi_rad), math.cos(phi_rad), 0.0])
        radial = np.array([math.cos(phi_rad), math.sin(phi_rad), 0.0])
        for side in (1.0, -1.0):
            segs.append(np.stack([end, end - 0.15 * tangent + side * 0.08 * radial])[None, :, :])
    out: FloatArray = np.concatenate(segs)
    return out


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
        self._imu: dict[str, schemas.ImuPacket] = {}
        self._truth: dict[str, bytes] = {}
        self._nodes: dict[str, dict[str, Any]] = {}
        self._slots: dict[str, int] = {}
        self.swing_limit_deg: Callable[[str], float] = lambda device_id: HookThresholds().swing_warn_deg
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.updates = 0
        # A browser is connected (set by the drawing thread every frame; True until it runs): without one, the hub's
        # outputs and packets are not kept and the scene is not redrawn.
        self.watched = True
        self.server.initial_camera.position = (-6.0, -9.0, 6.0)
        self.server.initial_camera.look_at = (1.0, 3.0, 0.5)
        s = self.server.scene
        s.add_grid("/ground", width=20.0, height=20.0, cell_size=1.0, plane="xy")
        s.add_frame("/world", axes_length=0.5, axes_radius=0.01)
        gui = self.server.gui
        gui.add_markdown(LEGEND)
        self.pick = gui.add_dropdown("Device", options=(ALL,), initial_value=ALL)
        self.show_fused = gui.add_checkbox("Show fused", initial_value=True)
        self.show_raw = gui.add_checkbox("Show raw", initial_value=False)
        self.show_truth = gui.add_checkbox("Show ground truth", initial_value=True)
        self.status = gui.add_markdown("waiting for data")

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    # callbacks: hub (event loop) and bus (zenoh threads) only store values
    @listens_to("attitude", "swing")
    def on_hub(self, topic: str, model: schemas.WireModel) -> None:
        if not self.watched:
            return
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

    def on_packet(self, packet: schemas.Packet) -> None:
        """Hub packet sink: the newest IMU packet of each device with a fused attitude (for the raw layer)."""
        if self.watched and isinstance(packet, schemas.ImuPacket) and packet.device_id in self.devices:
            self._imu[packet.device_id] = packet

    def on_truth(self, key: str, payload: bytes) -> None:
        self._keep(self._truth, key, payload)

    def _keep(self, store: dict[str, bytes], key: str, payload: bytes) -> None:
        """Latest payload per device, only for devices with a fused attitude (anyone may publish on these keys)."""
        device_id = key.rsplit("/", 2)[1]
        if device_id in self.devices:
            store[device_id] = payload

    def attach(self, service: GatewayService) -> None:
        def swing_limit_deg(device_id: str) -> float:  # the device's own limit (override on the kind default)
            try:
                return float(getattr(service.pipeline.effective("hook", device_id)[1], "swing_warn_deg", 5.0))
            except (KeyError, RuntimeError):  # a settings change in flight: keep the default this frame
                return HookThresholds().swing_warn_deg

        self.swing_limit_deg = swing_limit_deg
        service.hub.listeners.append(self.on_hub)
        service.hub.packet_listeners.append(self.on_packet)
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
        """Scene nodes of one device under `/dev/{id}`, placed in its own slot; the truth layer is offset."""
        nodes = self._nodes.get(device_id)
        if nodes is not None:
            return nodes
        s, base = self.server.scene, f"/dev/{device_id}"
        slot = self._slots.setdefault(device_id, len(self._slots))
        lift = HOOK_LIFT_M if kind == "hook" else 0.0  # a hook hangs above the ground with its load
        nodes = {"root": s.add_frame(base, show_axes=False, position=(0.0, slot * SLOT_M, lift))}
        s.add_frame(f"{base}/truth", show_axes=False, position=GHOST_OFFSET_M)
        for layer, rgb in (("fused", FUSED_RGB), ("raw", RAW_RGB), ("truth", TRUTH_RGB)):
            pts = np.zeros((2, 2, 3))
            nodes[f"{layer}_line"] = s.add_line_segments(f"{base}/{layer}/line", pts, rgb, thickness=0.04)
            nodes[f"{layer}_frame"] = s.add_frame(f"{base}/{layer}/frame", axes_length=0.4, axes_radius=0.02)
            if kind == "hook":
                ghost = layer == "truth"  # hook block and load hanging from the hook frame
                f = f"{base}/{layer}/frame"
                block = (0.35, 0.25, 0.5)
                nodes[f"{layer}_hook"] = s.add_box(f"{f}/hook", color=rgb, wireframe=ghost, dimensions=block,
                                                   position=(0.0, 0.0, -0.25))  # fmt: skip
                nodes[f"{layer}_load"] = s.add_box(f"{f}/load", color=rgb if ghost else (200, 140, 40),
                                                   dimensions=(0.9, 0.9, 0.6), position=(0.0, 0.0, -1.0),
                                                   wireframe=ghost)  # fmt: skip
        if kind == "rod":
            nodes["water"] = s.add_box(f"{base}/water", color=(60, 130, 200), dimensions=(7.0, 4.0, 0.02),
                                       position=(2.5, 0.0, WATER_Z_M), opacity=0.35)  # fmt: skip
            nodes["fishline"] = s.add_line_segments(f"{base}/fishline", np.zeros((2, 2, 3)), (40, 40, 40),
                                                    thickness=0.015)  # fmt: skip
            nodes["bait"] = s.add_icosphere(f"{base}/bait", radius=0.07, color=(220, 60, 60))
        elif kind == "hook":
            top = np.array([0.0, 0.0, HOOK_ROPE_M])
            mast_top = [-3.5, 0.0, HOOK_ROPE_M + 0.3]
            boom = np.array([[[-3.5, 0.0, -HOOK_LIFT_M], mast_top], [mast_top, top]])
            nodes["boom"] = s.add_line_segments(f"{base}/boom", boom, (235, 180, 40), thickness=0.12)
            nodes["boom_tip"] = s.add_box(f"{base}/boom_tip", color=(90, 90, 90), dimensions=(0.3, 0.3, 0.3),
                                          position=tuple(top))  # fmt: skip
            nodes["torsion"] = s.add_line_segments(f"{base}/torsion", np.zeros((1, 2, 3)), (210, 40, 200),
                                                   thickness=0.03)  # fmt: skip
            nodes["cone_deg"] = None
        nodes["label"] = s.add_label(f"{base}/label", device_id, position=(0.0, 0.0, 0.3))
        self._nodes[device_id] = nodes
        return nodes

    def _hook_extras(self, nodes: dict[str, Any], device_id: str, d: DeviceView, visible: bool) -> None:
        """Swing cone (rebuilt when the limit changes) and the torsion arc at the fused hook."""
        limit = self.swing_limit_deg(device_id)
        if nodes["cone_deg"] != limit:
            verts, faces = cone_mesh(np.array([0.0, 0.0, HOOK_ROPE_M]), HOOK_ROPE_M + 0.5, math.radians(limit))
            nodes["cone"] = self.server.scene.add_mesh_simple(
                f"/dev/{device_id}/cone", verts, faces, color=(230, 120, 40), opacity=0.15, side="double"
            )
            nodes["cone_deg"] = limit
        nodes["cone"].visible = visible
        nodes["torsion"].visible = visible and d.swing is not None
        if visible and d.swing is not None:
            _, hook = hook_geometry(d.fused / np.linalg.norm(d.fused), HOOK_ROPE_M)
            phi = math.radians(d.swing["torsion_deg"])
            nodes["torsion"].points = torsion_arc(hook + np.array([0.0, 0.0, 0.3]), phi)

    def _place(self, nodes: dict[str, Any], layer: str, kind: str, q: FloatArray | None, d: DeviceView,
               visible: bool) -> None:  # fmt: skip
        show = visible and q is not None and bool(np.all(np.isfinite(q)))
        for suffix in ("line", "frame", "hook", "load"):
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
            if layer == "fused":
                line = fishing_line(tip, WATER_Z_M)
                nodes["fishline"].points = segments(line)
                nodes["bait"].position = tuple(line[-1])
        elif kind == "hook":
            top, tip = hook_geometry(q, HOOK_ROPE_M)
            nodes[f"{layer}_line"].points = np.stack([top, tip])[None, :, :]
        else:  # a plain IMU: its board's frame above the slot, the line along its body z
            tip = np.array([0.0, 0.0, IMU_HEIGHT_M])
            nodes[f"{layer}_line"].points = np.stack([tip, tip + 0.6 * quat.rotate(q, np.array([0.0, 0.0, 1.0]))])[None]
        nodes[f"{layer}_frame"].position = tuple(tip)
        nodes[f"{layer}_frame"].wxyz = tuple(q)

    def step(self) -> None:
        """One scene update: the picker's options, then every device (or only the picked one) in its slot."""
        ids = sorted(self.devices)
        if (ALL, *ids) != tuple(self.pick.options):
            current = self.pick.value
            self.pick.options = (ALL, *ids)
            self.pick.value = current if current in ids else ALL  # type: ignore[misc]
        picked = self.pick.value
        for device_id, d in list(self.devices.items()):
            nodes = self._node_set(device_id, d.kind)
            on = picked in (ALL, device_id)
            nodes["root"].visible = on
            if not on:
                continue
            raw_q = None
            imu = self._imu.get(device_id)
            acc = None if imu is None else np.asarray(imu.acc_m_s2[-1], dtype=np.float64)
            if self.show_raw.value and imu is not None and acc is not None and np.linalg.norm(acc) > 1e-6:
                mag = None if imu.mag_uT is None else np.asarray(imu.mag_uT[-1], dtype=np.float64)
                raw_q = raw_attitude(acc, mag)
            truth = self._latest(self._truth, device_id, "quat_wxyz")
            self._place(nodes, "fused", d.kind, d.fused, d, self.show_fused.value)
            self._place(nodes, "raw", d.kind, raw_q, d, self.show_raw.value)
            self._place(nodes, "truth", d.kind, truth, d, self.show_truth.value)
            if d.kind == "hook":
                self._hook_extras(nodes, device_id, d, self.show_fused.value)
        lines = []
        for device_id in ids if picked == ALL else [picked]:
            dv = self.devices.get(device_id)
            if dv is None:
                continue
            e = np.degrees(quat.to_euler(dv.fused))
            text = f"**{device_id}** ({dv.kind}) roll {e[0]:.1f}° pitch {e[1]:.1f}° yaw {e[2]:.1f}°"
            if dv.swing:
                text += f", swing {dv.swing['swing_deg']:.1f}° torsion {dv.swing['torsion_deg']:.1f}°"
            lines.append(text)
        if lines:
            self.status.content = "  \n".join(lines[:12]) + (f"  \n… {len(lines) - 12} more" if len(lines) > 12 else "")
        self.updates += 1

    def _loop(self) -> None:
        period = 1.0 / self.rate_hz
        while not self._stop.wait(period):
            try:
                self.watched = bool(self.server.get_clients())
                if self.watched:
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


def has_clients(app: Any) -> bool:
    """Whether the app's 3-D view runs and a browser is connected to it (any thread)."""
    view: View3D | None = getattr(app.state, "view3d", None)
    if view is None:
        return False
    try:
        return bool(view.server.get_clients())
    except Exception:  # stopping
        return False


@router.get("/view3d", include_in_schema=False)
def open_view3d(request: Request) -> RedirectResponse:
    """Start the viser server if needed and redirect to it (same host name the browser used)."""
    view = ensure_view3d(request.app)
    host = request.url.hostname or "127.0.0.1"
    return RedirectResponse(f"http://{host}:{view.port}/", status_code=307)


@router.get("/api/view3d", tags=["health"])
async def view3d_info(request: Request) -> dict[str, Any]:
    """Whether the 3-D view runs, its port and scene updates so far."""
    view: View3D | None = getattr(request.app.state, "view3d", None)
    if view is None:
        return {"running": False}
    return {"running": True, "port": view.port, "updates": view.updates, "devices": sorted(view.devices),
            "clients": len(view.server.get_clients()), "t_s": time.time()}  # fmt: skip
