# commonlight bench tracking on the bundled sample (the only case that needs no rendering): the
# tables, the JSON figures and the plot; unknown cases are usage errors.
source "$(dirname "$0")/lib.sh"

expect_exit 0 "$COMMONLIGHT" bench tracking --source "$SRC" --data "$TMP/data" --cases desk --frames 8 \
    --json "$TMP/bench.json" --plot "$TMP/bench.png"
expect_text "libapriltag estimate_tag_pose" "$TMP/out"
expect_text "bundle + filter + edges" "$TMP/out"
expect_text "tracking mode" "$TMP/out"
[[ -s "$TMP/bench.png" ]] || fail "no plot"
python3 - "$TMP/bench.json" <<'PY'
import json, sys
j = json.load(open(sys.argv[1]))["cases"]["desk"]
for key in ("apriltag_estimate_tag_pose", "single_tag", "bundle", "bundle_filter", "bundle_filter_edges",
            "bundle_filter_tracking_mode"):
    e = j[key]
    assert e["count"] > 0, key
    for stat in ("p50", "p95", "max"):
        assert e["rot_deg"][stat] >= 0 and e["trans_mm"][stat] >= 0, (key, stat)
# The scale bias of each single-tag method, and the alignment without the dilation beside it.
for key in ("apriltag_estimate_tag_pose", "single_tag_refined_corners", "single_tag_aligned_without_dilation", "single_tag"):
    assert abs(j[key]["range_bias_pct"]) < 5, key
assert abs(j["single_tag"]["range_bias_pct"]) < 0.5
# The response each aligned tag measured: the sample's sRGB camera read as sRGB keeps the assumed one.
e = j["single_tag_response_exponent"]
assert e["measured"] > 0 and e["replaced"] == 0, e
assert 0.77 < e["min"] <= e["p5"] <= e["p50"] <= e["p95"] <= e["max"] < 1.3, e
assert j["single_over_apriltag_trans_p50"] > 0
# The stage as play and live run it (tracking mode): its ratio, and the first frame detected in full.
assert j["tracking_mode_over_detector_cpu"] > 0
assert 1 <= j["tracking_mode_full_frame_detections"] <= 8
assert j["stage_cpu_ms_mean_tracking_mode"]["detect"] > 0
assert len(j["sweep"]) == 6
assert {(e["decimate"], e["tracking_mode"]) for e in j["sweep"]} == {(d, m) for d in (1, 2, 3) for m in (False, True)}
# Every frame of the sample has a camera pose at decimate 1 (full frame and tracking mode).
assert all(e["count"] == 8 for e in j["sweep"] if e["decimate"] == 1)
PY
expect_exit 2 "$COMMONLIGHT" bench tracking --cases nope
expect_text "nope" "$TMP/err"
echo "bench tracking: ok"
