#!/usr/bin/env bash
# live in a window (under Xvfb) on a GigE Vision camera: the bundled sample served by serve-gige
# over the real protocol, inside a private network namespace (Aravis discovery broadcasts). Once a
# tracked frame is shown with the lighting's first snapshot, a screenshot (key s) has the virtual
# objects and the overlay's panel; the frames match the recording bit for bit (ground truth by
# pixels).
source "$(dirname "$0")/netns.sh"
source "$(dirname "$0")/lib.sh"
[[ -n "${DISPLAY:-}" ]] || { echo "skipped: no DISPLAY (run under xvfb-run)"; exit 77; }
command -v xdotool >/dev/null || { echo "skipped: xdotool is not installed"; exit 77; }
PNGCHECK="$(dirname "$0")/pngcheck.py"
start_serve_gige --sequence "$SAMPLE" --loop

"$COMMONLIGHT" live --camera aravis:127.0.0.1 --scene "$SAMPLE/scene.yaml" --ground-truth "$SAMPLE" \
    --settle 0.5 --screenshots "$TMP" --out "$TMP/out" >"$TMP/live.out" 2>"$TMP/live.err" &
pid=$!
BG_PIDS+=("$pid")
wid=$(find_window "$pid") || { cat "$TMP/live.err"; fail "no commonlight window appeared (DISPLAY $DISPLAY from the namespace)"; }
# The first lighting update takes a while (minutes under the sanitizers).
wait_for_title "$wid" "| tracked |*| lighting v[1-9]" 240
xdotool key --window "$wid" s
wait_for_log "screenshot: $TMP/screenshot-0.png" "$TMP/live.err"
ctrl_c_live "$pid"
frames=$(json_get "$TMP/out/metrics.json" frames)
(( $(json_get "$TMP/out/metrics.json" frames_with_pose) == frames )) || fail "not every frame tracked"
[[ $(json_get "$TMP/out/metrics.json" frames_without_truth) == 0 ]] || fail "served frames that are not the recording's"
counts=$(python3 "$PNGCHECK" "$TMP/screenshot-0.png" "cube=0,120,640,480,g > r + 25 and g > b + 15 and g < 200" \
    "panel=0,0,320,120,r > 230 and g > 230 and b > 230")
cube=$(count_of cube "$counts"); panel=$(count_of panel "$counts")
echo "screenshot: virtual cube $cube, panel text $panel pixels"
(( cube > 200 )) || fail "the virtual cube is not in the window ($cube green pixels)"
(( panel > 300 )) || fail "no overlay panel in the window ($panel white pixels)"
echo PASS
