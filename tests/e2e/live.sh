# commonlight live --headless on mock cameras: the pipeline's pose error matches play's on the
# same recording, the photometry lock, recording while live, reconnection after a disconnect
# (fault injection), and the errors. The GigE (Aravis) run of the same pipeline is in
# tests/e2e/aravis_*.sh.
source "$(dirname "$0")/lib.sh"

# pose_p50 METRICS KEY: the p50 of pose_error.KEY.
pose_p50() {
    python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["pose_error"][sys.argv[2]]["p50"])' "$1" "$2"
}

# 1. play --sync is the reference: every frame, ground truth by timestamp.
expect_exit 0 "$COMMONLIGHT" play "$SAMPLE" --sync --metrics "$TMP/play.json"
play_rot=$(pose_p50 "$TMP/play.json" rot_deg)
play_mm=$(pose_p50 "$TMP/play.json" trans_mm)
python3 -c "import sys; sys.exit(0 if 0 < $play_rot < 0.2 and 0 < $play_mm < 5 else 1)" ||
    fail "play's pose error is off: $play_rot deg, $play_mm mm"

# 2. live on the recording served as a camera (at a quarter of its rate, so that a sanitizer
# build's slower tracking still takes most frames: live drops what it cannot keep up with),
# ground truth found by pixels.
expect_exit 0 "$COMMONLIGHT" live --camera "replay:$SAMPLE?speed=0.25" --scene "$SAMPLE/scene.yaml" --ground-truth "$SAMPLE" \
    --headless --out "$TMP/live" --settle 0.2 --record "$TMP/rec"
expect_text "photometry locked after 0.2 s" "$TMP/err"
expect_text "pose error against ground truth" "$TMP/out"
[[ -s "$TMP/live/poses.csv" ]] || fail "no poses.csv"
[[ $(head -1 "$TMP/live/poses.csv") == "timestamp_ns,status,tx,ty,tz,qw,qx,qy,qz" ]] || fail "bad poses.csv header"
frames=$(json_get "$TMP/live/metrics.json" frames)
(( frames >= SAMPLE_FRAMES / 2 )) || fail "live took only $frames of $SAMPLE_FRAMES frames"
with_truth=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["pose_error"]["frames"])' "$TMP/live/metrics.json")
(( with_truth == $(json_get "$TMP/live/metrics.json" frames_with_pose) )) || fail "frames without a ground-truth match"
live_rot=$(pose_p50 "$TMP/live/metrics.json" rot_deg)
live_mm=$(pose_p50 "$TMP/live/metrics.json" trans_mm)
# Same pipeline, same frames (a few may be dropped live): the same error within noise.
python3 -c "import sys; sys.exit(0 if abs($live_rot - $play_rot) < 0.02 and abs($live_mm - $play_mm) < 0.4 else 1)" ||
    fail "live's pose error ($live_rot deg, $live_mm mm) differs from play's ($play_rot deg, $play_mm mm)"
# The recording made while live holds the frames live took, bit for bit.
[[ $(rows "$TMP/rec/cam0/data.csv") == "$frames" ]] || fail "recorded $(rows "$TMP/rec/cam0/data.csv") of $frames frames"
# (Live may have dropped the sample's first frames on a loaded machine: the recording's first frame
# is compared with the sample's frame of the same timestamp, which names the file.)
rec_first=$(frame_file "$TMP/rec" 0)
[[ -f "$SAMPLE/cam0/data/$(basename "$rec_first")" ]] || fail "recorded frame $(basename "$rec_first") is not in the sample"
cmp -s "$rec_first" "$SAMPLE/cam0/data/$(basename "$rec_first")" || fail "recorded frame $(basename "$rec_first") differs from the sample's"

# 3. The camera disconnects every 20 frames: live reconnects and goes on to 50 frames.
expect_exit 0 "$COMMONLIGHT" live --camera "replay:$SAMPLE?fault_disconnect_after=20" --scene "$SAMPLE/scene.yaml" \
    --ground-truth "$SAMPLE" --headless --frames 50 --out "$TMP/reconnect"
expect_text "camera lost: replay:" "$TMP/err"
expect_text "reconnected to replay:" "$TMP/err"
[[ $(json_get "$TMP/reconnect/metrics.json" frames) == 50 ]] || fail "expected 50 frames across reconnects"
(( $(json_get "$TMP/reconnect/metrics.json" reconnects) >= 2 )) || fail "expected at least 2 reconnects"
[[ $(json_get "$TMP/reconnect/metrics.json" frames_with_pose) == 50 ]] || fail "tracking did not restart after a reconnect"

# 4. Without reconnection the device error ends the run: exit 4 naming the camera.
expect_exit 4 "$COMMONLIGHT" live --camera "replay:$SAMPLE?fault_disconnect_after=5" --scene "$SAMPLE/scene.yaml" \
    --ground-truth "$SAMPLE" --headless --no-reconnect
expect_text "device disconnected" "$TMP/err"

# 5. Without --calib (and without --ground-truth) a recording's own sensor.yaml gives the intrinsics.
expect_exit 0 "$COMMONLIGHT" live --camera "replay:$SAMPLE?rate=max" --scene "$SAMPLE/scene.yaml" --headless --frames 5 \
    --no-lighting --settle 0
expect_text "live: replay:" "$TMP/out"

# 6. Errors: a window without a display (device, naming DISPLAY and --headless), a missing scene (bad input), a bad URI option (usage).
expect_exit 4 env -u DISPLAY -u WAYLAND_DISPLAY "$COMMONLIGHT" live --camera "replay:$SAMPLE" --scene "$SAMPLE/scene.yaml" \
    --ground-truth "$SAMPLE"
expect_text "DISPLAY" "$TMP/err"
expect_text "--headless" "$TMP/err"
expect_exit 3 "$COMMONLIGHT" live --camera "replay:$SAMPLE" --scene "$TMP/missing.yaml" --headless
expect_text "missing.yaml" "$TMP/err"
expect_exit 2 "$COMMONLIGHT" live --camera "replay:$SAMPLE?bogus=1" --scene "$SAMPLE/scene.yaml" --ground-truth "$SAMPLE" --headless
expect_text "bogus" "$TMP/err"
echo "live: ok (play p50 $play_rot deg / $play_mm mm; live p50 $live_rot deg / $live_mm mm over $frames frames)"
