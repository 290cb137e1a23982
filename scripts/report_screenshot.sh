#!/usr/bin/env bash
# Screenshot of an `rtf report` page as a person sees it: Debian's headless Chromium.
# usage: scripts/report_screenshot.sh report.html out.png [WIDTHxHEIGHT]   (default 1300x2400)
# Needs `chromium` (apt-get install chromium).
set -euo pipefail
page=$(realpath "$1")
out=$(realpath -m "$2")
size=${3:-1300x2400}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
chromium --headless --no-sandbox --disable-gpu --hide-scrollbars \
    --user-data-dir="$tmp/profile" --window-size="${size/x/,}" \
    --screenshot="$tmp/shot.png" "file://$page" >/dev/null 2>&1
mv "$tmp/shot.png" "$out"
echo "screenshot: $out"
