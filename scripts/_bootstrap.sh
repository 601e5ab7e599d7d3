# Sourced by scripts/run and scripts/test: creates .venv and installs the project with its
# extras when .venv is missing or pyproject.toml changed since the last install.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
STAMP="$VENV/.qlap-installed"
PY="${PYTHON:-python3}"
if [ ! -x "$VENV/bin/python" ]; then
    echo "[bootstrap] creating $VENV" >&2
    "$PY" -m venv "$VENV"
fi
# MuJoCo's offscreen renderer (qlap snapshot, its test) needs OSMesa on a machine without a
# display; install it when we can (root with apt), otherwise the snapshot test skips and says so.
if ! ldconfig -p 2>/dev/null | grep -q libOSMesa && [ "$(id -u)" = 0 ] \
        && command -v apt-get >/dev/null; then
    echo "[bootstrap] installing libosmesa6 (offscreen rendering)" >&2
    (apt-get install -y -q libosmesa6 >/dev/null 2>&1 \
        || (apt-get update -q >/dev/null 2>&1 && apt-get install -y -q libosmesa6 >/dev/null 2>&1)) \
        || echo "[bootstrap] libosmesa6 not installed; snapshots will be skipped" >&2
fi
if [ ! -f "$STAMP" ] || [ "$ROOT/pyproject.toml" -nt "$STAMP" ]; then
    echo "[bootstrap] installing qlap-runtime with extras [dev,experiments]" >&2
    "$VENV/bin/python" -m pip install -q --upgrade pip >&2
    "$VENV/bin/python" -m pip install -q -e "$ROOT[dev,experiments]" >&2
    touch "$STAMP"
fi
# The agent's numeric loops are compiled by numba on first use and cached beside their source
# (qlap_runtime/qlap/kernels.py): compile them here, once, so that the first run of the UI
# does not stall ~15 s over its first batches. A short headless run reaches every kernel.
KSTAMP="$VENV/.qlap-kernels"
if [ ! -f "$KSTAMP" ] || [ "$ROOT/qlap_runtime/qlap/kernels.py" -nt "$KSTAMP" ] \
        || [ "$STAMP" -nt "$KSTAMP" ]; then
    echo "[bootstrap] compiling the agent's numeric kernels (once, ~20 s)" >&2
    KTMP="$(mktemp -d)"
    if "$VENV/bin/python" -m qlap_runtime.cli run --headless --placement sync --world core \
            --steps 21000 --seed 0 --out "$KTMP/run" --quiet >/dev/null 2>&1; then
        touch "$KSTAMP"
    else
        echo "[bootstrap] could not compile them now; the first run will" >&2
    fi
    rm -rf "$KTMP"
fi
