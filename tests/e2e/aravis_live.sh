#!/usr/bin/env bash
# `commonlight live --camera aravis:127.0.0.1 --headless` on the bundled desk sample served by
# serve-gige (as RGB8: GigE Vision carries no JPEG): the whole pipeline over the real GigE
# protocol gives the same pose error as `play` on the recording; and `bench capture` runs its
# GigE cases (ours and GStreamer's aravissrc) on the same served camera. Inside a private
# network namespace (Aravis discovery broadcasts on every interface).
if [[ -z ${COMMONLIGHT_IN_PRIVATE_NETNS:-} ]]; then
    if ! unshare -n true 2>/dev/null; then
        echo "SKIP: unshare -n is not permitted here (needs CAP_SYS_ADMIN or user namespaces)" >&2
        exit 77
    fi
    COMMONLIGHT_IN_PRIVATE_NETNS=1 exec unshare -n -- bash "$0" "$@"
fi
source "$(dirname "$0")/lib.sh"
ip link set lo up || skip "cannot bring lo up in the private network namespace"
SERVER_PID=
trap '[[ -n $SERVER_PID ]] && kill -9 $SERVER_PID 2>/dev/null; rm -rf "$TMP"' EXIT

"$COMMONLIGHT" serve-gige --sequence "$SAMPLE" --loop >"$TMP/server.out" 2>"$TMP/server.err" &
SERVER_PID=$!
for _ in $(seq 1 200); do
    grep -q "^serving " "$TMP/server.out" 2>/dev/null && break
    kill -0 $SERVER_PID 2>/dev/null || { cat "$TMP/server.err"; fail "serve-gige exited"; }
    sleep 0.05
done
grep -q "^serving " "$TMP/server.out" || fail "serve-gige did not start"

pose_p50() {
    python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["pose_error"][sys.argv[2]]["p50"])' "$1" "$2"
}

# The reference: play on the recording itself.
expect_exit 0 "$COMMONLIGHT" play "$SAMPLE" --sync --metrics "$TMP/play.json"
play_rot=$(pose_p50 "$TMP/play.json" rot_deg)
play_mm=$(pose_p50 "$TMP/play.json" trans_mm)

# live over GigE: 90 frames (the sample loops), ground truth found by the frames' pixels.
expect_exit 0 "$COMMONLIGHT" live --camera aravis:127.0.0.1 --scene "$SAMPLE/scene.yaml" --ground-truth "$SAMPLE" \
    --headless --frames 90 --out "$TMP/live" --settle 0.5
[[ $(json_get "$TMP/live/metrics.json" frames) == 90 ]] || fail "expected 90 frames"
with_pose=$(json_get "$TMP/live/metrics.json" frames_with_pose)
(( with_pose == 90 )) || fail "only $with_pose of 90 frames tracked"
[[ $(json_get "$TMP/live/metrics.json" frames_without_truth) == 0 ]] ||
    fail "served frames that are not bit-identical to the recording"
live_rot=$(pose_p50 "$TMP/live/metrics.json" rot_deg)
live_mm=$(pose_p50 "$TMP/live/metrics.json" trans_mm)
python3 -c "import sys; sys.exit(0 if abs($live_rot - $play_rot) < 0.02 and abs($live_mm - $play_mm) < 0.4 else 1)" ||
    fail "live over GigE ($live_rot deg, $live_mm mm) differs from play ($play_rot deg, $play_mm mm)"

# bench capture's GigE cases run and deliver frames.
expect_exit 0 "$COMMONLIGHT" bench capture --sequence "$SAMPLE" --gige 127.0.0.1 --seconds 1 --json "$TMP/bench.json"
python3 - "$TMP/bench.json" <<'PY' || fail "bench capture: a case delivered nothing"
import json, sys
cases = {c["case"]: c for c in json.load(open(sys.argv[1]))["cases"]}
for name in ("replay 30 fps", "aravis 30 fps", "aravis max rate", "gstreamer aravissrc 30 fps"):
    assert cases[name]["frames"] > 0 and not cases[name]["error"], (name, cases.get(name))
PY
echo "aravis_live: ok (play p50 $play_rot deg / $play_mm mm; live over GigE p50 $live_rot deg / $live_mm mm)"
