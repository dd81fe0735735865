#!/usr/bin/env bash
# What the test suite needs beyond Python: a headless Chromium, to open each run's
# index.html as a reader would (tests/bench/test_page.py). Installed from Debian's
# packages where it is missing and this user may; otherwise that one test is skipped
# and this says why. Idempotent and quick when Chromium is there.
set -uo pipefail

for browser in chromium chromium-browser google-chrome; do
    command -v "$browser" >/dev/null 2>&1 && exit 0
done
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    echo "test-deps: installing Debian's chromium (for the page test)"
    if DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends chromium >/tmp/ssga-test-deps.log 2>&1 \
        || { apt-get update >>/tmp/ssga-test-deps.log 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends chromium >>/tmp/ssga-test-deps.log 2>&1; }; then
        exit 0
    fi
    echo "test-deps: could not install chromium (log: /tmp/ssga-test-deps.log); the browser test of index.html will be skipped"
else
    echo "test-deps: no chromium, and no apt-get as root to install it; the browser test of index.html will be skipped"
fi
exit 0
