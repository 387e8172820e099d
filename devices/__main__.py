"""Start every simulated device (rod, environment ball, hook) in one go: `python -m devices --help`."""

from __future__ import annotations

import argparse
import sys


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m devices", description=__doc__)
    parser.parse_args(argv)
    print("no devices yet", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
