#!/usr/bin/env bash
# Set up forecast_design from a fresh clone: a virtual environment in .venv
# with the pinned dependencies (requirements.lock) and the package itself.
# With --test, also the Debian packages the test suite needs (ARM cross-compiler
# and emulator for the export tests), installed only when missing.
set -euo pipefail
cd "$(dirname "$0")/.."

want_test=0
for arg in "$@"; do
  case "$arg" in
    --test) want_test=1 ;;
    *) echo "setup.sh: unknown option '$arg' (known: --test)" >&2; exit 2 ;;
  esac
done

python=""
for candidate in python3.11 python3; do
  if command -v "$candidate" >/dev/null 2>&1 && "$candidate" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
    python="$candidate"; break
  fi
done
[ -n "$python" ] || { echo "setup.sh: Python 3.11 is required" >&2; exit 2; }

[ -x .venv/bin/python ] || "$python" -m venv .venv

# Reinstall only when the pins or the project metadata changed.
stamp=.venv/.forecast-design-stamp
digest=$(cat requirements.lock pyproject.toml | sha256sum | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$digest" ]; then
  .venv/bin/python -m pip install --quiet --upgrade pip
  .venv/bin/python -m pip install --quiet -r requirements.lock
  .venv/bin/python -m pip install --quiet --no-deps -e .
  echo "$digest" > "$stamp"
fi

if [ "$want_test" = 1 ]; then
  missing=()
  for pkg in gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm; do
    dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
  done
  if [ "${#missing[@]}" -gt 0 ]; then
    if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
      apt-get update -qq >/dev/null && \
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null \
        || echo "setup.sh: could not install ${missing[*]}; the ARM export tests will be skipped" >&2
    else
      echo "setup.sh: ${missing[*]} missing and apt-get unavailable; the ARM export tests will be skipped" >&2
    fi
  fi
fi
