#!/usr/bin/env bash
# live --headless on the simulated camera (sim:, path traced on the camera's thread, 1 sample per
# pixel): tracking, the lighting thread and the compositor (offscreen) run on what it renders.
# A few frames only: the simulator renders about one frame per second here (much slower under
# the sanitizers: --timeout keeps a slow frame from counting as a lost camera).
source "$(dirname "$0")/lib.sh"
DESK="$SRC/data/scenes/desk"

expect_exit 0 "$COMMONLIGHT" live --camera "sim:$DESK/scene.yaml?trajectory=$DESK/trajectory.yaml&spp=1&rate=max" \
    --scene "$DESK/scene.yaml" --headless --composite --frames 6 --settle 0 --timeout 120 --out "$TMP/live"
expect_text "photometry locked" "$TMP/err"
[[ $(json_get "$TMP/live/metrics.json" reconnects) == 0 ]] || fail "the simulated camera was lost"
[[ $(json_get "$TMP/live/metrics.json" frames) == 6 ]] || fail "expected 6 frames"
with_pose=$(json_get "$TMP/live/metrics.json" frames_with_pose)
(( with_pose >= 5 )) || fail "only $with_pose of 6 simulated frames tracked"
[[ $(( $(rows "$TMP/live/poses.csv") - 1 )) == 6 ]] || fail "expected 6 poses (and the header) in poses.csv"
python3 - "$TMP/live/metrics.json" <<'PY'
import json, sys
m = json.load(open(sys.argv[1]))
c = m["compositor"]
assert c["frames"] >= 1 and c["frames"] + c["replaced"] == m["frames"], c  # each tracked frame shown or replaced
assert c["threads"] == "pipeline thread + main thread", c
assert "lighting" in m and m["lighting"]["observations"]["submitted"] == m["frames"], m.get("lighting")
PY
echo "live_sim: ok ($with_pose of 6 simulated frames tracked)"
