#!/usr/bin/env bash
# live in a window (under Xvfb) on a replay: camera: keys sent with xdotool, screenshots read back
# from the window (key s) and checked: the composite shows the virtual objects, the overlay shows
# its panel of figures and the REC mark (recording from the start with --record), the tag
# detections view (d pressed four times) draws the tags' outlines, r stops the recording and
# starts a new one beside it, tab and the arrow keys move the selected virtual object.
source "$(dirname "$0")/lib.sh"
[[ -n "${DISPLAY:-}" ]] || { echo "skipped: no DISPLAY (run under xvfb-run)"; exit 77; }
command -v xdotool >/dev/null || { echo "skipped: xdotool is not installed"; exit 77; }
PNGCHECK="$(dirname "$0")/pngcheck.py"

"$COMMONLIGHT" live --camera "replay:$SAMPLE?loop=1&speed=0.5" --scene "$SAMPLE/scene.yaml" --ground-truth "$SAMPLE" \
    --no-lighting --settle 0 --screenshots "$TMP" --out "$TMP/out" --record "$TMP/rec" \
    >"$TMP/live.out" 2>"$TMP/live.err" &
pid=$!
BG_PIDS+=("$pid")
wid=$(find_window "$pid") || { kill "$pid" 2>/dev/null; cat "$TMP/live.err"; fail "no commonlight window appeared"; }
sleep 1
# Each key is handled at the next frame (or within 0.1 s without one); a screenshot is what the
# window shows then: wait for each one before the next keys. The composite's screenshot once the
# cube is drawn: on a loaded machine the first frames can come before the first pose (up to 10
# screenshots, a second apart; the checks below read the last).
shot=0
for _ in $(seq 1 10); do
    xdotool key --window "$wid" s
    wait_for_log "screenshot: $TMP/screenshot-$shot.png" "$TMP/live.err"
    cube=$(count_of cube "$(python3 "$PNGCHECK" "$TMP/screenshot-$shot.png" "cube=0,0,640,480,g > r + 25 and g > b + 25 and g < 200")")
    (( cube > 200 )) && break
    shot=$((shot + 1))
    sleep 1
done
composite="$TMP/screenshot-$(( cube > 200 ? shot : shot - 1 )).png"
xdotool key --window "$wid" Tab Right Right Right Up d
wait_for_log "view: proxies (wireframe)" "$TMP/live.err"
# One key at a time, each waited for.
for view in "view: elements" "view: ratio" "view: tag detections"; do
    xdotool key --window "$wid" d
    wait_for_log "$view" "$TMP/live.err"
done
sleep 1
details="screenshot-$(( cube > 200 ? shot + 1 : shot ))"
xdotool key --window "$wid" s
wait_for_log "screenshot: $TMP/$details.png" "$TMP/live.err"
xdotool key --window "$wid" r
wait_for_log "recording stopped: " "$TMP/live.err"
xdotool key --window "$wid" r
wait_for_log "recording to $TMP/rec-2" "$TMP/live.err"
# No --frames: under load (other windows' tests beside it, sanitizers) a fixed count could run out
# before the keys are through. The run ends with Ctrl-C once the second recording holds a frame.
for _ in $(seq 1 900); do
    [[ -f "$TMP/rec-2/cam0/data.csv" ]] && (( $(rows "$TMP/rec-2/cam0/data.csv") > 0 )) && break
    sleep 0.1
done
ctrl_c_live "$pid"
expect_text "selected: " "$TMP/live.err"

# The composite view: the green virtual cube is there; the overlay's panel (white text, top left)
# and the REC mark (a red dot, top right); no bright green tag outlines.
counts=$(python3 "$PNGCHECK" "$composite" \
    "cube=0,0,640,480,g > r + 25 and g > b + 25 and g < 200" "panel=0,0,320,120,r > 230 and g > 230 and b > 230" \
    "rec=-200,0,-1,40,r > 180 and g < 60 and b < 60" "outline=0,0,640,480,g > 200 and r < 120 and b < 140")
cube=$(count_of cube "$counts"); panel=$(count_of panel "$counts"); rec=$(count_of rec "$counts"); outline=$(count_of outline "$counts")
echo "$(basename "$composite"): cube $cube, panel text $panel, REC $rec, tag outline $outline pixels"
(( cube > 200 )) || fail "the virtual cube is not in the window ($cube green pixels)"
(( panel > 300 )) || fail "no overlay panel in the window ($panel white pixels top left)"
(( rec > 30 )) || fail "no REC mark in the window ($rec red pixels top right)"
(( outline < 100 )) || fail "tag outlines in the composite view ($outline)"
# The tag detections view: the four tags' outlines.
outline1=$(count_of outline "$(python3 "$PNGCHECK" "$TMP/$details.png" "outline=0,0,640,480,g > 200 and r < 120 and b < 140")")
echo "$details: tag outline $outline1 pixels"
(( outline1 > 400 )) || fail "the tag detections view shows no tags ($outline1 outline pixels)"

# Both recordings are sequences; together they hold at most the frames live took.
for seq in "$TMP/rec" "$TMP/rec-2"; do
    [[ -f "$seq/cam0/data.csv" ]] || fail "no recording in $seq"
    (( $(rows "$seq/cam0/data.csv") > 0 )) || fail "$seq holds no frame"
done
taken=$(json_get "$TMP/out/metrics.json" frames)
(( $(rows "$TMP/rec/cam0/data.csv") + $(rows "$TMP/rec-2/cam0/data.csv") <= taken )) || fail "more frames recorded than taken"
expect_text "recorded " "$TMP/live.out"
echo PASS
