#!/usr/bin/env bash
# live in a window (under Xvfb): keys sent with xdotool (d: a debug view and back, tab and the
# arrow keys: the selected virtual object moves, s: a screenshot), the screenshot read from the
# window shows the virtual objects; no display: exit 4.
source "$(dirname "$0")/lib.sh"
[[ -n "${DISPLAY:-}" ]] || { echo "skipped: no DISPLAY (run under xvfb-run)"; exit 77; }
command -v xdotool >/dev/null || { echo "skipped: xdotool is not installed"; exit 77; }

"$COMMONLIGHT" live --camera "replay:$SAMPLE?loop=1&speed=0.5" --scene "$SAMPLE/scene.yaml" --ground-truth "$SAMPLE" \
    --no-lighting --settle 0 --frames 120 --screenshots "$TMP" --out "$TMP/out" >"$TMP/live.out" 2>"$TMP/live.err" &
pid=$!
wid=""
for _ in $(seq 1 100); do
    # This process's window (other GL tests may have windows of their own on the same display).
    wid=$(xdotool search --all --pid "$pid" --name '^commonlight' 2>/dev/null | head -1 || true)
    [[ -n "$wid" ]] && break
    sleep 0.2
done
[[ -n "$wid" ]] || { kill "$pid" 2>/dev/null; cat "$TMP/live.err"; fail "no commonlight window appeared"; }
sleep 1
xdotool key --window "$wid" s
sleep 0.5
xdotool key --window "$wid" Tab Right Right Right Up d
sleep 0.5
xdotool key --window "$wid" d d d
sleep 0.5
wait "$pid" || { cat "$TMP/live.err"; fail "live exited with $?"; }
expect_text "screenshot: " "$TMP/live.err"
expect_text "selected: " "$TMP/live.err"
expect_text "view: proxies (wireframe)" "$TMP/live.err"
[[ -s "$TMP/screenshot-0.png" ]] || fail "no screenshot written"
# The screenshot shows the virtual objects: the composite differs from the recorded frame, and
# saturated green pixels of the green cube are there.
python3 - "$TMP/screenshot-0.png" <<'PY'
import sys, zlib, struct
data = open(sys.argv[1], "rb").read()
assert data[:8] == b"\x89PNG\r\n\x1a\n"
pos, idat, w = 8, b"", 0
while pos < len(data):
    n, kind = struct.unpack(">I4s", data[pos:pos + 8])
    body = data[pos + 8:pos + 8 + n]
    if kind == b"IHDR":
        w, h, depth, colour = struct.unpack(">IIBB", body[:10])
        assert depth == 8 and colour == 2, (depth, colour)
    if kind == b"IDAT":
        idat += body
    pos += 12 + n
raw = zlib.decompress(idat)
stride = 3 * w
rows, prev = [], bytearray(stride)
for y in range(h):
    f, line = raw[y * (stride + 1)], bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
    for i in range(stride):
        a = line[i - 3] if i >= 3 else 0
        b = prev[i]
        c = prev[i - 3] if i >= 3 else 0
        if f == 1: line[i] = (line[i] + a) & 255
        elif f == 2: line[i] = (line[i] + b) & 255
        elif f == 3: line[i] = (line[i] + (a + b) // 2) & 255
        elif f == 4:
            p = a + b - c
            pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
            line[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
    rows.append(line)
    prev = line
green = sum(1 for line in rows for x in range(w) if line[3 * x + 1] > line[3 * x] + 25 and line[3 * x + 1] > line[3 * x + 2] + 25)
assert green > 200, green
print("green pixels of the virtual cube in the screenshot:", green)
PY
echo PASS
