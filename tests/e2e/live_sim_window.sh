#!/usr/bin/env bash
# live in a window (under Xvfb) on the simulated camera (sim:, path traced, 1 sample per pixel):
# once a tracked frame is shown, a screenshot (key s) has the virtual objects composited into the
# rendered scene and the overlay's panel; then Ctrl-C. A few frames only (about one rendered per second).
source "$(dirname "$0")/lib.sh"
[[ -n "${DISPLAY:-}" ]] || { echo "skipped: no DISPLAY (run under xvfb-run)"; exit 77; }
command -v xdotool >/dev/null || { echo "skipped: xdotool is not installed"; exit 77; }
PNGCHECK="$(dirname "$0")/pngcheck.py"
DESK="$SRC/data/scenes/desk"

"$COMMONLIGHT" live --camera "sim:$DESK/scene.yaml?trajectory=$DESK/trajectory.yaml&spp=1&rate=max" --scene "$DESK/scene.yaml" \
    --no-lighting --settle 0 --timeout 120 --screenshots "$TMP" --out "$TMP/out" >"$TMP/live.out" 2>"$TMP/live.err" &
pid=$!
BG_PIDS+=("$pid")
wid=$(find_window "$pid") || { cat "$TMP/live.err"; fail "no commonlight window appeared"; }
wait_for_title "$wid" "| tracked |"
xdotool key --window "$wid" s
wait_for_log "screenshot: $TMP/screenshot-0.png" "$TMP/live.err"
# No --frames (a fixed count could run out before the key is handled under load): Ctrl-C once the
# screenshot is taken.
ctrl_c_live "$pid"
frames=$(json_get "$TMP/out/metrics.json" frames)
(( frames >= 1 )) || fail "no frame taken"
(( $(json_get "$TMP/out/metrics.json" frames_with_pose) >= frames - 1 )) || fail "simulated frames not tracked"
counts=$(python3 "$PNGCHECK" "$TMP/screenshot-0.png" "cube=0,120,640,480,g > r + 25 and g > b + 15 and g < 200" \
    "panel=0,0,320,120,r > 230 and g > 230 and b > 230")
cube=$(count_of cube "$counts"); panel=$(count_of panel "$counts")
echo "screenshot: virtual cube $cube, panel text $panel pixels"
(( cube > 300 )) || fail "the virtual cube is not in the window ($cube green pixels)"
(( panel > 300 )) || fail "no overlay panel in the window ($panel white pixels)"
echo PASS
