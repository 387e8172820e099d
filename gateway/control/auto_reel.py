"""Auto reel (fish walking) of the rods in the gateway, and its watchdog: which rods are in auto mode, their
controllers, the commands that go out and the safety stops (data lost, rod offline).

Pure bookkeeping: times are passed in (gateway wall time `now_s`, device time `t_s`), commands and events are
appended to an `Output`; the runner publishes them. A rod's controller lives while its fusion does (`forget` when
the pipeline drops the device); its watchdog record (`ReelWatch`) lives for the auto session.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from gateway.config import RodThresholds
from gateway.kinds.base import Output, ReelEvent


@dataclass
class ReelWatch:
    """Auto-reel bookkeeping of one rod; it outlives the device's fusion state (a filter restart drops that)."""

    since_s: float  # gateway time the newest rod data reached the controller (or of the first watchdog look)
    device_t_s: float | None = None  # device time of that data's last sample
    fields: dict[str, Any] | None = None  # last command sent
    lost: bool = False  # a data-lost stop went out and no fresh data has been used since


@dataclass
class ReelController:
    """A running fish-walking controller and the device time it was last stepped at (its steps move forward)."""

    ctrl: Any  # gateway.control.fish_walking.FishWalkingController
    step_t_s: float = -math.inf

    @property
    def settings(self) -> Any:
        return self.ctrl.settings


def controller_class() -> Any:
    """The fish-walking controller class, or None when gateway.control.fish_walking is missing."""
    try:
        from gateway.control.fish_walking import FishWalkingController
    except ImportError:
        return None
    return FishWalkingController


def reel_timeout_s() -> float:
    """The fish-walking controller's data timeout, s (its default; 0.3 s when the module is missing)."""
    try:
        from gateway.control.fish_walking import FishWalkingSettings
    except ImportError:
        return 0.3
    return FishWalkingSettings().attitude_timeout_s


class AutoReel:
    """Auto mode of every rod: `on` (rod id -> True), controllers of rods with live fusion, watchdog records.

    `watchdog_s`: a rod in auto whose newest data is older than this has its controller stepped by `tick`."""

    def __init__(self, watchdog_s: float, thresholds: Callable[[str], RodThresholds], on: Iterable[str] = ()
                 ) -> None:  # fmt: skip
        self.watchdog_s = watchdog_s
        self._thresholds = thresholds
        self.on: dict[str, bool] = dict.fromkeys(on, True)
        self.controllers: dict[str, ReelController] = {}
        self._watch: dict[str, ReelWatch] = {}

    def switch(self, device_id: str, on: bool, live: bool) -> None:
        """Auto on or off; `live`: the rod's fusion runs, so a controller starts now (else with its first block)."""
        self._watch.pop(device_id, None)  # a fresh watchdog record per auto session
        self.controllers.pop(device_id, None)
        if on:
            self.on[device_id] = True
            if live:
                self.attach(device_id)
        else:
            self.on.pop(device_id, None)

    def attach(self, device_id: str) -> None:
        """A rod's fusion (re)started: give it a controller if it is in auto mode."""
        if not self.on.get(device_id):
            return
        cls = controller_class()
        if cls is None:
            return
        from gateway.control.fish_walking import FishWalkingSettings

        th = self._thresholds(device_id)
        s = FishWalkingSettings(theta2_rad=math.radians(th.line_switch_deg), theta3_rad=math.radians(th.line_limit_deg),
                                line_breaking_n=th.line_breaking_n)  # fmt: skip
        self.controllers[device_id] = ReelController(cls(s))

    def forget(self, device_id: str) -> None:
        """The rod's fusion was dropped (restart, failure): its controller goes with it; auto stays on."""
        self.controllers.pop(device_id, None)

    def step(self, device_id: str, t_s: float, pitch_from_rest_rad: float, status: Any, now_s: float,
             out: Output) -> None:  # fmt: skip
        """Step the controller on a fused block's last sample (device time `t_s`); send the command if it changed.
        `status`: the rod's latest ReelStatus, or None."""
        from gateway.control.fish_walking import Observation

        rc = self.controllers.get(device_id)
        if rc is None:
            return
        t_step = t_s
        if t_s <= rc.step_t_s:
            if rc.step_t_s - t_s > rc.ctrl.settings.attitude_timeout_s:  # device clock restarted (reboot)
                rc.ctrl.enable()
            else:  # a watchdog step's estimate ran ahead of this late sample: keep the controller's time moving on
                t_step = rc.step_t_s + 1e-3
        obs = Observation(t_s, pitch_from_rest_rad, None, status.tension_n if status else None,
                          status.line_out_m if status else None)  # fmt: skip
        decision = rc.ctrl.step(t_step, obs)
        rc.step_t_s = t_step
        w = self._watched(device_id, now_s)
        w.since_s, w.device_t_s = now_s, t_s
        self._send(device_id, w, decision.command_fields(), decision.reason, now_s, out)

    def tick(self, now_s: float) -> Output:
        """Watchdog tick at gateway wall time (see `Pipeline.tick_reel`)."""
        out = Output()
        for dev_id in [d for d, on in self.on.items() if on]:
            w = self._watched(dev_id, now_s)
            if now_s - w.since_s < self.watchdog_s:  # fresh: the packets step the controller
                continue
            rc = self.controllers.get(dev_id)
            if rc is not None and w.device_t_s is not None:
                t = w.device_t_s + (now_s - w.since_s)
                if t <= rc.step_t_s:
                    continue
                decision = rc.ctrl.step(t, None)
                rc.step_t_s = t
                self._send(dev_id, w, decision.command_fields(), decision.reason, now_s, out)
            elif now_s - w.since_s > reel_timeout_s():
                self._send(dev_id, w, {"action": "stop"}, "timeout", now_s, out)
        return out

    def offline(self, device_id: str, now_s: float) -> Output:
        """The rod's liveliness token vanished (see `Pipeline.reel_offline`)."""
        out = Output()
        if self.on.get(device_id):
            w = self._watched(device_id, now_s)
            w.fields, w.lost = {"action": "stop"}, True
            out.reel_commands.append((device_id, w.fields))
            out.reel_events.append(ReelEvent(device_id, "reel_offline", now_s, {"command": w.fields}))
        return out

    def _watched(self, device_id: str, now_s: float) -> ReelWatch:
        w = self._watch.get(device_id)
        if w is None:
            w = self._watch[device_id] = ReelWatch(now_s)
        return w

    def _send(self, device_id: str, w: ReelWatch, fields: dict[str, Any], reason: str, now_s: float,
              out: Output) -> None:  # fmt: skip
        """Queue `fields` if they changed; a data-lost stop is always sent (and logged) the first time."""
        lost = reason == "timeout" and not w.lost
        w.lost = reason == "timeout"
        if lost:
            details = {"data_age_s": round(now_s - w.since_s, 3), "command": fields}
            out.reel_events.append(ReelEvent(device_id, "reel_data_lost", now_s, details))
        if lost or fields != w.fields:
            w.fields = fields
            out.reel_commands.append((device_id, fields))
