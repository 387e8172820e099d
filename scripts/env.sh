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
# gateway/fusion/__pycache__: do it here, once per checkout, with a progress line, so the first gateway start is fast.
if ! ls "$ROOT"/gateway/fusion/__pycache__/*.nbi >/dev/null 2>&1; then
  echo "[env] compiling the fusion kernels once (cached for later starts)" >&2
  (cd "$ROOT" && "$ROOT/.venv/bin/python" -m gateway --prepare) >&2
fi
export PATH="$ROOT/.venv/bin:$PATH"
cd "$ROOT"
