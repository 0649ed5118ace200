#!/usr/bin/env bash
# `commonlight live --camera aravis:127.0.0.1 --headless` on the bundled desk sample served by
# serve-gige (as RGB8: GigE Vision carries no JPEG): the whole pipeline over the real GigE
# protocol gives the same pose error as `play` on the recording; and `bench capture` runs its
# GigE cases (ours and GStreamer's aravissrc) on the same served camera. Inside a private
# network namespace (Aravis discovery broadcasts on every interface).
source "$(dirname "$0")/netns.sh"
source "$(dirname "$0")/lib.sh"
start_serve_gige --sequence "$SAMPLE" --loop

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
