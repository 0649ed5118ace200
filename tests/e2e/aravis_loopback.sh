#!/usr/bin/env bash
# The Aravis backend against `commonlight serve-gige` (Aravis's fake GigE camera serving a
# sequence) over loopback, inside a private network namespace (Aravis discovery broadcasts on
# every interface, so it must never run outside one): enumeration, 100 frames recorded
# bit-identical and in order, exposure and gain, the server killed mid-stream (device error,
# exit 4, naming the camera), a restarted server and a new recording, a clean SIGTERM exit,
# Bayer and the bundled MJPEG sample (served as RGB8).
source "$(dirname "$0")/netns.sh"
source "$(dirname "$0")/lib.sh"
TOOL="${COMMONLIGHT_BINARY_DIR:?set by CTest}/tests/mocks/gige_sequence_tool"
[[ -x $TOOL ]] || fail "missing $TOOL (built with the tests)"

"$TOOL" make "$TMP/seq" 120 320 240 gray8 60 >/dev/null
start_serve_gige --sequence "$TMP/seq" --loop
expect_text "at 127.0.0.1" "$TMP/server.out"

# Enumeration (discovery, inside this namespace only).
expect_exit 0 "$COMMONLIGHT" cameras
expect_text "aravis:Aravis-Fake-commonlight" "$TMP/out"
expect_text "127.0.0.1" "$TMP/out"
expect_text "gray8 320x240" "$TMP/out"
expect_exit 0 "$COMMONLIGHT" cameras --json
python3 - "$TMP/out" <<'PY' || fail "cameras --json does not list the served camera"
import json, sys
cams = [c for c in json.load(open(sys.argv[1]))["cameras"] if c["backend"] == "aravis"]
assert any(c["uri"] == "aravis:Aravis-Fake-commonlight" and "127.0.0.1" in c["name"] and
           {"format": "gray8", "width": 320, "height": 240} in
           [{k: f[k] for k in ("format", "width", "height")} for f in c["formats"]] for c in cams), cams
PY

# 100 frames, bit-identical to the served sequence and in order.
expect_exit 0 "$COMMONLIGHT" record --camera aravis:127.0.0.1 --out "$TMP/rec" --frames 100
expect_text "recorded 100 frames" "$TMP/out"
"$TOOL" compare "$TMP/seq" "$TMP/rec" 100 || fail "recorded frames differ from the served ones"
# Device sequence numbers and device timestamps increase.
python3 - "$TMP/rec/cam0/meta.csv" <<'PY' || fail "meta.csv: sequence numbers or timestamps"
import sys
rows = [l.strip().split(",") for l in open(sys.argv[1]) if not l.startswith("#")]
seq = [int(r[1]) for r in rows]
ts = [int(r[0]) for r in rows]
assert len(rows) == 100, len(rows)
assert all(b > a for a, b in zip(seq, seq[1:])), seq  # gaps: frames lost (counted), never reordered
assert all(b > a for a, b in zip(ts, ts[1:]))
PY

# The device by its id (discovery) works too.
expect_exit 0 "$COMMONLIGHT" record --camera aravis:Aravis-Fake-commonlight --out "$TMP/rec_id" --frames 5

# Exposure and gain: the device registers change and every frame's metadata carries them.
expect_exit 0 "$COMMONLIGHT" record --camera "aravis:127.0.0.1?exposure_us=2500&gain=3" --out "$TMP/rec_eg" --frames 5
python3 - "$TMP/rec_eg/cam0/meta.csv" <<'PY' || fail "meta.csv does not carry exposure 2500 and gain 3"
import sys
rows = [l.strip().split(",") for l in open(sys.argv[1]) if not l.startswith("#")]
assert len(rows) == 5 and all(float(r[2]) == 2500 and float(r[3]) == 3 for r in rows), rows
PY
arv-tool-0.8 -a 127.0.0.1 control ExposureTimeAbs GainRaw >"$TMP/regs" 2>&1 || fail "arv-tool: $(cat "$TMP/regs")"
grep -Eq "ExposureTimeAbs = 2500(\.0+)?( |$)" "$TMP/regs" || { cat "$TMP/regs"; fail "ExposureTimeAbs not 2500"; }
grep -Eq "GainRaw = 3( |$)" "$TMP/regs" || { cat "$TMP/regs"; fail "GainRaw not 3"; }

# The server killed mid-stream: a device error naming the camera, exit 4, the frames kept.
"$COMMONLIGHT" record --camera "aravis:127.0.0.1?timeout_ms=1000" --out "$TMP/rec_kill" >"$TMP/kill.out" 2>"$TMP/kill.err" &
rec_pid=$!
wait_for_rows "$TMP/rec_kill" 10
kill -9 $SERVER_PID
wait $SERVER_PID 2>/dev/null || true
SERVER_PID=
set +e
wait $rec_pid
code=$?
set -e
[[ $code == 4 ]] || { cat "$TMP/kill.err"; fail "record after the server died: exit $code, expected 4"; }
expect_text "aravis:127.0.0.1" "$TMP/kill.err"
[[ $(rows "$TMP/rec_kill/cam0/data.csv") -ge 10 ]] || fail "the frames before the error were not kept"

# Restart the server and reconnect.
start_serve_gige --sequence "$TMP/seq" --loop
expect_exit 0 "$COMMONLIGHT" record --camera aravis:127.0.0.1 --out "$TMP/rec2" --frames 20
"$TOOL" compare "$TMP/seq" "$TMP/rec2" 20 || fail "frames after the restart differ"

# SIGTERM stops the server cleanly.
kill -TERM $SERVER_PID
set +e
wait $SERVER_PID
code=$?
set -e
SERVER_PID=
[[ $code == 0 ]] || { cat "$TMP/server.err"; fail "serve-gige exit $code on SIGTERM"; }
expect_text "served " "$TMP/server.out"

# Without --loop, --frames N: the server sends N frames and exits by itself; the client then
# sees the camera go away (exit 4) with at most N frames recorded, every one as served.
start_serve_gige --sequence "$TMP/seq" --frames 15
expect_exit 4 "$COMMONLIGHT" record --camera "aravis:127.0.0.1?timeout_ms=1000" --out "$TMP/rec3"
expect_text "aravis:127.0.0.1" "$TMP/err"
set +e
wait $SERVER_PID
code=$?
set -e
SERVER_PID=
[[ $code == 0 ]] || fail "serve-gige --frames 15: exit $code"
expect_text "served 15 frames" "$TMP/server.out"
[[ $(rows "$TMP/rec3/cam0/data.csv") -le 15 ]] || fail "more than 15 frames from serve-gige --frames 15"
"$TOOL" compare "$TMP/seq" "$TMP/rec3" 5 || fail "frames of the limited server differ"

# Bayer mosaics (BayerGB8) and the bundled MJPEG sample (served as RGB8) arrive bit-identical.
"$TOOL" make "$TMP/bayer" 30 160 120 bayer_gbrg8 60 >/dev/null
start_serve_gige --sequence "$TMP/bayer" --loop
expect_exit 0 "$COMMONLIGHT" record --camera "aravis:127.0.0.1?format=bayer_gbrg8" --out "$TMP/rec_bayer" --frames 12
"$TOOL" compare "$TMP/bayer" "$TMP/rec_bayer" 12 || fail "bayer frames differ"
kill -TERM $SERVER_PID; wait $SERVER_PID || fail "serve-gige (bayer) did not exit cleanly"; SERVER_PID=
start_serve_gige --sequence "$SAMPLE" --loop
expect_text "rgb8 640x480" "$TMP/server.out"
expect_exit 0 "$COMMONLIGHT" record --camera aravis:127.0.0.1 --out "$TMP/rec_sample" --frames 12
"$TOOL" compare "$SAMPLE" "$TMP/rec_sample" 12 || fail "frames of the MJPEG sample differ from the decoded ones"
kill -TERM $SERVER_PID; wait $SERVER_PID || fail "serve-gige (sample) did not exit cleanly"; SERVER_PID=
echo PASS
