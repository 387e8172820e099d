# Source me: creates ./.venv on first use and (re)installs the project when pyproject.toml changes.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="${PYTHON:-python3}"
if [ ! -x "$ROOT/.venv/bin/python" ]; then
  echo "[env] creating $ROOT/.venv" >&2
  "$PY" -m venv "$ROOT/.venv"
  "$ROOT/.venv/bin/python" -m pip install -q --upgrade pip >&2
fi
STAMP="$ROOT/.venv/.installed-$(sha1sum "$ROOT/pyproject.toml" | cut -c1-12)"
if [ ! -f "$STAMP" ]; then
  echo "[env] installing the project and its dependencies" >&2
  "$ROOT/.venv/bin/python" -m pip install -q -e "$ROOT[dev]" >&2
  rm -f "$ROOT"/.venv/.installed-*
  touch "$STAMP"
fi
# numba compiles the fusion kernels on first use (~40 s on 2 cores, minutes on a loaded box) and caches them in
# __pycache__: do it here, with a progress line, so a gateway start is fast. Again whenever a gateway source changed
# since (an update recompiles the kernels it touched; with nothing to compile this takes ~2 s): a shard that compiles
# at its start under load falls behind and drops packets for minutes.
KSTAMP="$ROOT/.venv/.kernels-prepared"
if [ ! -f "$KSTAMP" ] || [ -n "$(find "$ROOT/gateway" -name '*.py' -newer "$KSTAMP" -print -quit)" ]; then
  echo "[env] compiling the fusion kernels (cached for later starts)" >&2
  (cd "$ROOT" && "$ROOT/.venv/bin/python" -m gateway --prepare) >&2
  touch "$KSTAMP"
fi
export PATH="$ROOT/.venv/bin:$PATH"
cd "$ROOT"
