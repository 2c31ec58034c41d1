#!/usr/bin/env bash
# Installs everything meshadv needs on a fresh machine and builds the Rust extension into the current Python.
# Idempotent: a second run only rebuilds what changed.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON="${PYTHON:-python3}"

# Mitsuba's fast CPU variant (llvm_ad_rgb) needs a recent LLVM shared library; scalar_rgb works without it.
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = "0" ] && ! ldconfig -p 2>/dev/null | grep -q "libLLVM.so.19\|libLLVM-19"; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null) \
        || echo "note: libllvm19 not installed; Mitsuba will use scalar_rgb" >&2
fi

# The perceptual-study page is tested in headless Chromium (tests/test_study_browser.py skips without it).
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = "0" ] && ! command -v chromedriver >/dev/null 2>&1; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null) \
        || echo "note: chromium not installed; the study page's browser test will be skipped" >&2
fi

"$PYTHON" -m pip install --quiet --disable-pip-version-check -r requirements.txt
# Editable install: maturin builds the native module meshadv._raster (release profile) into python/meshadv/.
"$PYTHON" -m pip install --quiet --disable-pip-version-check --no-build-isolation --no-deps -e .
"$PYTHON" -c "import meshadv._raster" || { echo "meshadv native module failed to import" >&2; exit 1; }
