#!/usr/bin/env bash
# expoctl's two commands. Each creates .venv (Python 3.11 + pip) and installs the pinned dependencies if needed.
#   ./run.sh pipeline   the whole pipeline at the default scale (dvc repro)
#   ./run.sh test       the test suite (what CI runs)
set -euo pipefail
cd "$(dirname "$0")"
VENV="${EXPOCTL_VENV:-.venv}"
PYTHON="${PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python3

setup() {
  local stamp="$VENV/.expoctl-installed"
  # optional extras to install besides test (CI adds camera: EXPOCTL_EXTRAS=test,camera)
  local extras="${EXPOCTL_EXTRAS:-test}"
  local have e stale=0
  have=",$(cat "$stamp" 2>/dev/null || true),"
  [ "$have" != ",," ] || have=",test,"  # stamps from before extras were recorded
  for e in ${extras//,/ }; do [[ "$have" == *",$e,"* ]] || stale=1; done
  if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ "$stale" = 1 ]; then
    [ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"
    "$VENV/bin/python" -m pip install -q --upgrade pip
    "$VENV/bin/python" -m pip install -q -e ".[$extras]"
    echo "$extras" > "$stamp"
  fi
  export PATH="$PWD/$VENV/bin:$PATH"
}

case "${1:-}" in
  pipeline)
    setup
    [ -d .git ] || { echo "run.sh: dvc needs a git checkout (git clone the repository)" >&2; exit 2; }
    shift
    dvc repro "$@"
    ;;
  test)
    setup
    shift
    python -m pytest "$@"
    ;;
  *)
    echo "usage: ./run.sh pipeline|test [args passed to dvc repro / pytest]" >&2
    exit 2
    ;;
esac
