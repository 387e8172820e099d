import numpy as np
import pytest

from gateway.fusion import registry
from gateway.fusion.registry import FILTERS, make_filter


def test_unknown_filter_names_the_known_ones():
    with pytest.raises(KeyError, match="unknown filter 'nope'"):
        make_filter("nope")


@pytest.mark.parametrize("name", sorted(FILTERS))
@pytest.mark.parametrize("use_mag", [True, False])
def test_every_registered_filter_builds_and_holds_a_level_still_attitude(name, use_mag):
    """Each name (paper variants included) builds, carries its registry name, and keeps a level, still sensor level
    within 0.5° over 2 s at 100 Hz."""
    acc = np.tile([0.0, 0.0, 9.81], (200, 1))
    mag = np.tile([0.0, 20.0, -40.0], (200, 1))
    f = make_filter(name, use_mag=use_mag)
    assert f.name == name
    f.initialise(acc[0], mag[0] if use_mag else None)
    q = f.run(np.zeros((200, 3)), acc, mag if use_mag else None, 0.01)
    tilt_deg = np.degrees(2 * np.arccos(np.clip(np.hypot(q[-1, 0], q[-1, 3]), -1, 1)))
    assert tilt_deg < 0.5


def test_paper_variants_are_the_papers_settings():
    from gateway.fusion.kf import FIG4_KP_RAD_S

    kf = registry.kf_paper()
    assert kf.settings.paper and kf.settings.fig4_kp_rad_s == FIG4_KP_RAD_S > 0  # type: ignore[attr-defined]
    assert registry.ekf_paper().settings.paper  # type: ignore[attr-defined]
    assert np.isinf(registry.mahony_paper().settings.integral_limit_rad_s)  # type: ignore[attr-defined]
    assert not make_filter("kf").settings.fig4_kp_rad_s  # type: ignore[attr-defined]
