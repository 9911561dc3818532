#!/usr/bin/env bash
# Opens a Rerun recording in the Rerun web viewer (served on 127.0.0.1 only) in headless
# Chromium, takes a screenshot and checks it is not blank (pixel variance, and not the
# viewer's empty welcome screen: the recording's colours must be there).
#
#   scripts/rerun-screenshot.sh RUN.rrd OUT.png [WIDTH HEIGHT [WAIT_SECONDS]]
#
# Installs what it needs when missing: chromium (apt-get), a venv with rerun-sdk==0.36.*
# (PyPI; $RERUN_VENV, default /tmp/dynapix-rerun-venv) and the npm package playwright-core
# ($RERUN_NODE_DIR, default /tmp/dynapix-rerun-node), which drives /usr/bin/chromium.
# Rerun's usage analytics are disabled before the viewer starts; Chromium runs with its
# background networking off. Exit 0 when the screenshot shows the recording.
set -euo pipefail
RRD=$(realpath "$1"); OUT=$(realpath -m "$2")
WIDTH=${3:-1600}; HEIGHT=${4:-900}; WAIT=${5:-45}
VENV=${RERUN_VENV:-/tmp/dynapix-rerun-venv}
NODE_DIR=${RERUN_NODE_DIR:-/tmp/dynapix-rerun-node}
HTTP_PORT=${RERUN_HTTP_PORT:-9190}
GRPC_PORT=${RERUN_GRPC_PORT:-9977}
[ -f "$RRD" ] || { echo "no recording $RRD" >&2; exit 2; }

if ! command -v chromium > /dev/null; then
  apt-get update -qq && apt-get install -y -qq chromium > /dev/null
fi
if [ ! -x "$VENV/bin/rerun" ]; then
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q "rerun-sdk==0.36.*"
fi
if [ ! -d "$NODE_DIR/node_modules/playwright-core" ]; then
  mkdir -p "$NODE_DIR"
  (cd "$NODE_DIR" && npm install --silent --no-audit --no-fund playwright-core@1 > /dev/null)
fi
"$VENV/bin/rerun" analytics disable > /dev/null 2>&1

# A viewer already serving these ports would be screenshotted instead of this recording.
for port in "$HTTP_PORT" "$GRPC_PORT"; do
  if (exec 3<> "/dev/tcp/127.0.0.1/$port") 2> /dev/null; then
    echo "port $port on 127.0.0.1 is in use (another viewer?); set RERUN_HTTP_PORT/RERUN_GRPC_PORT" >&2
    exit 2
  fi
done
LOG=$(mktemp); PROFILE=$(mktemp -d)
# In a process group of its own: `rerun` is a Python launcher whose viewer is a child process,
# and both must go when the script ends.
setsid "$VENV/bin/rerun" "$RRD" --web-viewer --bind 127.0.0.1 --port "$GRPC_PORT" \
  --web-viewer-port "$HTTP_PORT" > "$LOG" 2>&1 &
VIEWER=$!
cleanup() { kill -- -"$VIEWER" 2> /dev/null || kill "$VIEWER" 2> /dev/null || true; wait "$VIEWER" 2> /dev/null || true; rm -rf "$PROFILE" "$LOG"; }
trap cleanup EXIT
for _ in $(seq 60); do
  if (exec 3<> "/dev/tcp/127.0.0.1/$HTTP_PORT") 2> /dev/null; then break; fi
  sleep 0.5
done
URL="http://127.0.0.1:$HTTP_PORT/?url=$(python3 -c 'import sys,urllib.parse;print(urllib.parse.quote(sys.argv[1],safe=""))' "rerun+http://127.0.0.1:$GRPC_PORT/proxy")"

cat > "$NODE_DIR/shot.js" << 'EOF'
const { chromium } = require('playwright-core');
(async () => {
  const [url, out, width, height, wait, profile] = process.argv.slice(2);
  const ctx = await chromium.launchPersistentContext(profile, {
    executablePath: '/usr/bin/chromium',
    headless: true,
    viewport: { width: +width, height: +height },
    args: ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync',
      '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
  });
  const page = ctx.pages()[0] || await ctx.newPage();
  // Nothing but the local viewer may be reached.
  await page.route('**/*', (r) => {
    const u = new URL(r.request().url());
    return ['127.0.0.1', 'localhost'].includes(u.hostname) ? r.continue() : r.abort();
  });
  await page.goto(url);
  await page.waitForTimeout(+wait * 1000);
  await page.screenshot({ path: out });
  await ctx.close();
})().catch((e) => { console.error(e); process.exit(1); });
EOF
node "$NODE_DIR/shot.js" "$URL" "$OUT" "$WIDTH" "$HEIGHT" "$WAIT" "$PROFILE"

# Not blank: the pixels vary, and several colours of the recording are there (a blank page or
# the viewer's empty screen is a few greys).
"$VENV/bin/python" - "$OUT" << 'EOF'
import sys
import numpy as np
from PIL import Image
a = np.asarray(Image.open(sys.argv[1]).convert("RGB")).astype(np.int32)
std = float(a.std())
q = (a // 32).reshape(-1, 3)
colours = len({tuple(c) for c in q[:: max(1, len(q) // 200000)]})
saturated = float(((a.max(axis=2) - a.min(axis=2)) > 60).mean())
print(f"screenshot {sys.argv[1]}: {a.shape[1]}x{a.shape[0]}, pixel std {std:.1f}, "
      f"{colours} colour bins, {100 * saturated:.1f} % saturated pixels")
if std < 10 or colours < 20 or saturated < 0.01:
    sys.exit("the screenshot looks blank")
EOF
