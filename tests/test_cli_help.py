"""Every command answers `--help` (a usage line, exit 0): the commands are found, not listed, so a new one is covered.

A help text is a %-format string to argparse: a bare `%` in it ("10 %,") raised ValueError in `--help` alone
(bench.hook_suite, 2026-12-07), which no run with options would show."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _commands() -> list[str]:
    """Modules under bench/, devices/ and gateway/ run as `python -m`: a `__main__` guard, or a package's
    `__main__.py` (named by its package)."""
    found = []
    for top in ("bench", "devices", "gateway"):
        for path in sorted((ROOT / top).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            if path.name == "__main__.py":
                found.append(".".join(path.parent.relative_to(ROOT).parts))
            elif 'if __name__ == "__main__"' in text:
                found.append(".".join(path.with_suffix("").relative_to(ROOT).parts))
    return found


def test_the_commands_are_found() -> None:
    """The discovery itself: it finds the commands the README names (else every test below could pass on none)."""
    found = set(_commands())
    assert {"gateway", "bench.hook_suite", "devices.sim_hook", "gateway.calibrate"} <= found, sorted(found)


@pytest.mark.filterwarnings("ignore:.*found in sys.modules after import of package:RuntimeWarning")
@pytest.mark.parametrize("module", _commands())
def test_help(module: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "argv", [module, "--help"])
    with pytest.raises(SystemExit) as exit_:
        runpy.run_module(module, run_name="__main__", alter_sys=True)
    out = capsys.readouterr().out
    assert exit_.value.code in (0, None), f"{module} --help exited {exit_.value.code}"
    assert "usage:" in out, f"{module} --help printed no usage line: {out[:200]!r}"
