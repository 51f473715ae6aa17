#!/usr/bin/env bash
# Set up polycam's environment in ./.venv from the committed lock file (uv.lock).
#
# mrcal's wheels need CPython >= 3.12, so this first finds one:
#   $POLYCAM_PYTHON, then python3.13 / python3.12 / python3 on PATH, then pyenv's
#   versions (~/.pyenv/versions/3.1[2-3]*), then one that uv manages or can install.
# It then gets uv (already on PATH, or pip-installed into ./.tools), and runs
# `uv sync --locked`, which installs exactly the locked versions (with mrcal's
# pyfltk and opencv-python-headless requirements overridden away, see pyproject.toml).
# Re-running is cheap: uv only installs what changed.
set -euo pipefail
cd "$(dirname "$0")/.."

say() { echo "setup: $*" >&2; }

py_ok() {  # is $1 a CPython >= 3.12, < 3.14?
  "$1" - <<'PY' 2>/dev/null
import sys, platform
ok = platform.python_implementation() == "CPython" and (3, 12) <= sys.version_info[:2] < (3, 14)
raise SystemExit(0 if ok else 1)
PY
}

find_python() {
  local c
  if [ -n "${POLYCAM_PYTHON:-}" ]; then
    if py_ok "$POLYCAM_PYTHON"; then echo "$POLYCAM_PYTHON"; return 0; fi
    say "POLYCAM_PYTHON=$POLYCAM_PYTHON is not a CPython 3.12 or 3.13; looking elsewhere"
  fi
  for c in python3.13 python3.12 python3; do
    if command -v "$c" >/dev/null 2>&1 && py_ok "$(command -v "$c")"; then command -v "$c"; return 0; fi
  done
  for c in "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.1[23]*/bin/python3; do
    if [ -x "$c" ] && py_ok "$c"; then echo "$c"; return 0; fi
  done
  return 1
}

find_uv() {
  if command -v uv >/dev/null 2>&1; then command -v uv; return 0; fi
  if [ -x .tools/bin/uv ]; then echo "$PWD/.tools/bin/uv"; return 0; fi
  local boot
  boot=$(command -v python3 || true)
  [ -n "$boot" ] || { say "no python3 found to bootstrap uv"; return 1; }
  say "installing uv into ./.tools (from PyPI)"
  "$boot" -m venv .tools >&2 && .tools/bin/python -m pip install --quiet --disable-pip-version-check "uv>=0.5" >&2
  echo "$PWD/.tools/bin/uv"
}

UV=$(find_uv) || { say "could not get uv; install it (pip install uv) and re-run"; exit 1; }

PY=$(find_python || true)
if [ -z "$PY" ]; then
  PY=$("$UV" python find '>=3.12,<3.14' 2>/dev/null || true)
fi
if [ -z "$PY" ]; then
  say "no CPython >= 3.12 found; asking uv to install one"
  if "$UV" python install 3.12 >&2; then PY=$("$UV" python find '>=3.12,<3.14'); fi
fi
if [ -z "$PY" ]; then
  say "polycam needs CPython 3.12 or 3.13 (mrcal's wheels need >= 3.12)."
  say "Install one (e.g. 'pyenv install 3.12' or your distribution's python3.12) or set POLYCAM_PYTHON=/path/to/python3.12"
  exit 1
fi
say "using $PY ($("$PY" -c 'import sys; print(sys.version.split()[0])'))"

export UV_PROJECT_ENVIRONMENT="$PWD/.venv"
"$UV" sync --locked --python "$PY" --quiet >&2
.venv/bin/python - <<'PY'
import cv2, mrcal  # noqa: F401  the two packages whose install is delicate
assert hasattr(cv2, "aruco"), "cv2 without aruco: opencv-python-headless must not replace the contrib build"
PY
say "ready: .venv ($(.venv/bin/python -c 'import sys; print(sys.version.split()[0])'))"
