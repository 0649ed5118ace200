#!/usr/bin/env bash
# A camera that disconnects mid-run, in the window (under Xvfb): the fault-injecting camera
# disconnects every 45 frames, and while its recording's data.csv is moved away the camera cannot
# be reopened (as a device that is unplugged stays gone). The window says so (the overlay's
# "camera lost: reconnecting" banner, checked in a screenshot taken meanwhile) and stays
# responsive; once the file is back live reconnects and goes on. Ended with Ctrl-C (exit 130).
source "$(dirname "$0")/lib.sh"
[[ -n "${DISPLAY:-}" ]] || { echo "skipped: no DISPLAY (run under xvfb-run)"; exit 77; }
command -v xdotool >/dev/null || { echo "skipped: xdotool is not installed"; exit 77; }
PNGCHECK="$(dirname "$0")/pngcheck.py"
copy_sample "$TMP/seq"

"$COMMONLIGHT" live --camera "replay:$TMP/seq?loop=1&speed=0.5&fault_disconnect_after=45" --scene "$SAMPLE/scene.yaml" \
    --ground-truth "$SAMPLE" --no-lighting --settle 0 --timeout 2 --screenshots "$TMP" --out "$TMP/out" \
    >"$TMP/live.out" 2>"$TMP/live.err" &
pid=$!
BG_PIDS+=("$pid")
wid=$(find_window "$pid") || { cat "$TMP/live.err"; fail "no commonlight window appeared"; }
wait_for_log "photometry locked" "$TMP/live.err"

# Unplugged: the next reconnection attempts fail until the file is back.
mv "$TMP/seq/cam0/data.csv" "$TMP/data.csv.away"
wait_for_log "reconnecting to replay:$TMP/seq" "$TMP/live.err"
xdotool key --window "$wid" s
wait_for_log "screenshot: $TMP/screenshot-0.png" "$TMP/live.err"
reconnected=$(grep -c "reconnected to replay:" "$TMP/live.err" || true)
mv "$TMP/data.csv.away" "$TMP/seq/cam0/data.csv"
for _ in $(seq 1 300); do
    (( $(grep -c "reconnected to replay:" "$TMP/live.err" || true) > reconnected )) && break
    sleep 0.1
done
(( $(grep -c "reconnected to replay:" "$TMP/live.err" || true) > reconnected )) || { cat "$TMP/live.err"; fail "live did not reconnect"; }
# It goes on after the reconnection: a few more frames tracked.
rows_before=$(rows "$TMP/out/poses.csv")
for _ in $(seq 1 300); do
    (( $(rows "$TMP/out/poses.csv") > rows_before + 3 )) && break
    sleep 0.1
done
ctrl_c_live "$pid"
(( $(rows "$TMP/out/poses.csv") > rows_before + 3 )) || fail "no frames after the reconnection"
(( $(json_get "$TMP/out/metrics.json" reconnects) >= 1 )) || fail "no reconnection counted"
expect_text "camera lost: replay:$TMP/seq" "$TMP/live.err"

# The screenshot taken while the camera was gone shows the red banner across the middle.
banner=$(count_of banner "$(python3 "$PNGCHECK" "$TMP/screenshot-0.png" "banner=120,160,520,320,r > 140 and g < 70 and b < 70 and r > 3 * g")")
echo "screenshot while the camera was lost: $banner banner pixels"
(( banner > 5000 )) || fail "the window does not show that the camera is lost ($banner banner pixels)"
echo PASS
