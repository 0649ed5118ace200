# commonlight track: on the bundled sample (a sequence with ground truth), a folder of images,
# one image, and bad input. The figures themselves are checked by tests/tracking and the bench.
source "$(dirname "$0")/lib.sh"

header='image,timestamp_ns,tag_id,c0x,c0y,c1x,c1y,c2x,c2y,c3x,c3y,tx,ty,tz,qw,qx,qy,qz,status,pose_timestamp_ns,ambiguity_ratio,alt_tx,alt_ty,alt_tz,alt_qw,alt_qx,alt_qy,alt_qz,verified'

# 1. The sample with its scene: a header, one frame row per frame, tag rows with poses.
expect_exit 0 "$COMMONLIGHT" track "$SAMPLE" --out "$TMP/poses.csv"
[[ $(head -1 "$TMP/poses.csv") == "$header" ]] || fail "bad header: $(head -1 "$TMP/poses.csv")"
frame_rows=$(awk -F, 'NR > 1 && $3 == -1' "$TMP/poses.csv" | wc -l)
[[ $frame_rows == "$SAMPLE_FRAMES" ]] || fail "expected $SAMPLE_FRAMES frame rows, got $frame_rows"
tracked=$(awk -F, 'NR > 1 && $3 == -1 && $19 == "tracked"' "$TMP/poses.csv" | wc -l)
[[ $tracked == "$SAMPLE_FRAMES" ]] || fail "expected every frame tracked, got $tracked"
tag_rows=$(awk -F, 'NR > 1 && $3 >= 0 && $19 == "ok"' "$TMP/poses.csv" | wc -l)
(( tag_rows >= 3 * SAMPLE_FRAMES )) || fail "expected at least 3 tags per frame, got $tag_rows rows"
# Every row has 29 fields; quaternions are unit length.
awk -F, 'NR > 1 && NF != 29 { exit 1 }' "$TMP/poses.csv" || fail "a row without 29 fields"
# The sample's tags are all decoded (verified 0 on every tag row, empty on frame rows).
awk -F, 'NR > 1 && (($3 >= 0 && $29 != "0") || ($3 == -1 && $29 != "")) { exit 1 }' "$TMP/poses.csv" ||
    fail "the verified column: 0 on decoded tags, empty on frame rows"
expect_text "0 verified)" "$TMP/err"
# Poses are for the middle of the exposure: the sample's meta.csv has 10 ms, so 5 ms after the timestamp.
awk -F, 'NR > 1 && $20 != $2 + 5000000 { exit 1 }' "$TMP/poses.csv" || fail "pose_timestamp_ns is not mid-exposure"
awk -F, 'NR > 1 && $15 != "" { n = $15*$15 + $16*$16 + $17*$17 + $18*$18; if (n < 0.999999 || n > 1.000001) exit 1 }' \
    "$TMP/poses.csv" || fail "a quaternion that is not unit length"
# The summary reports the error against the sample's ground truth, well under a degree.
expect_text "pose error against groundtruth/cam_poses.csv ($SAMPLE_FRAMES frames)" "$TMP/err"
rot_p95=$(sed -n 's/.*rotation p50 [0-9.]* p95 \([0-9.]*\) max.*/\1/p' "$TMP/err")
python3 -c "import sys; sys.exit(0 if float('$rot_p95') < 1.0 else 1)" || fail "rotation p95 $rot_p95 deg"

# 1b. Tags too small to decode are verified where the scene's big tags put them: one rendered
# frame of data/scenes/tiny (tags 2-13 of 6-10 px), verified 1 on some of them, never on 0 and 1.
expect_exit 0 "$COMMONLIGHT" sim --scene "$SRC/data/scenes/tiny/scene.yaml" --trajectory "$SRC/data/scenes/tiny/tiny.yaml" \
    --out "$TMP/tiny" --frames 1 --spp 4 --no-radiance
expect_exit 0 "$COMMONLIGHT" track "$TMP/tiny" --out "$TMP/tiny.csv"
verified=$(awk -F, 'NR > 1 && $29 == 1 && $3 >= 2 && $3 <= 13 && $19 == "ok"' "$TMP/tiny.csv" | wc -l)
(( verified >= 3 )) || fail "expected tiny tags verified, got $verified"
awk -F, 'NR > 1 && ($3 == 0 || $3 == 1) && $29 != 0 { exit 1 }' "$TMP/tiny.csv" || fail "the anchors are decoded"
expect_text "$verified verified)" "$TMP/err"

# 2. Standard output when there is no --out; tracking mode gives the same frame rows.
expect_exit 0 "$COMMONLIGHT" track "$SAMPLE" --tracking-mode
[[ $(head -1 "$TMP/out") == "$header" ]] || fail "no CSV on stdout"
[[ $(awk -F, 'NR > 1 && $3 == -1 && $19 == "tracked"' "$TMP/out" | wc -l) == "$SAMPLE_FRAMES" ]] ||
    fail "tracking mode lost frames"

# 3. A folder of photos with --calib and --tag-size: single-tag poses, no world.
mkdir "$TMP/photos"
for i in 0 20 40; do cp "$(frame_file "$SAMPLE" $i)" "$TMP/photos/photo_$i.jpg"; done
expect_exit 0 "$COMMONLIGHT" track "$TMP/photos" --calib "$SRC/data/scenes/desk/calib.yaml" --tag-size 0.08 \
    --out "$TMP/photos.csv"
[[ $(awk -F, 'NR > 1 && $3 == -1' "$TMP/photos.csv" | wc -l) == 3 ]] || fail "expected 3 frame rows"
[[ $(awk -F, 'NR > 1 && $3 >= 0 && $19 == "ok"' "$TMP/photos.csv" | wc -l) -ge 9 ]] || fail "expected tag poses"
awk -F, 'NR > 1 && $3 >= 0 && $2 != 0 { exit 1 }' "$TMP/photos.csv" || fail "photos have timestamp 0"
expect_text "photo_0.jpg" "$TMP/photos.csv"

# 4. A single image.
expect_exit 0 "$COMMONLIGHT" track "$TMP/photos/photo_20.jpg" --calib "$SRC/data/scenes/desk/calib.yaml" \
    --tag-size 0.08
[[ $(awk -F, 'NR > 1 && $3 >= 0' "$TMP/out" | wc -l) -ge 3 ]] || fail "expected tags in one image"

# 5. A corrupt image among good ones: its row says so, the others are tracked, exit 3 naming it.
head -c 2000 "$TMP/photos/photo_40.jpg" > "$TMP/photos/photo_30.jpg"
expect_exit 3 "$COMMONLIGHT" track "$TMP/photos" --calib "$SRC/data/scenes/desk/calib.yaml" --tag-size 0.08 \
    --out "$TMP/corrupt.csv"
expect_text "photo_30.jpg" "$TMP/err"
expect_text "photo_30.jpg,0,-1,,,,,,,,,,,,,,,,unreadable," "$TMP/corrupt.csv"
# Photos have no exposure: their poses are for their timestamp (0).
awk -F, 'NR > 1 && $3 >= 0 && $20 != 0 { exit 1 }' "$TMP/corrupt.csv" || fail "photos' pose_timestamp_ns is not 0"
[[ $(awk -F, 'NR > 1 && $3 >= 0 && $19 == "ok"' "$TMP/corrupt.csv" | wc -l) -ge 9 ]] || fail "good photos lost"

# 6. Tags the scene does not place are reported, not posed, and leave the bundle alone.
cp -r "$SAMPLE" "$TMP/seq"
python3 - "$TMP/seq/scene.yaml" <<'PY'
import sys
p = sys.argv[1]
lines = open(p).read().splitlines()
out = [l for l in lines if "{id: 3," not in l]
open(p, "w").write("\n".join(out) + "\n")
PY
expect_exit 0 "$COMMONLIGHT" track "$TMP/seq" --out "$TMP/unknown.csv"
awk -F, 'NR > 1 && $3 == 3 && $19 != "unknown_tag" { exit 1 }' "$TMP/unknown.csv" || fail "tag 3 should be unknown"
[[ $(awk -F, 'NR > 1 && $3 == -1 && $19 == "tracked"' "$TMP/unknown.csv" | wc -l) == "$SAMPLE_FRAMES" ]] ||
    fail "the bundle should track with tags 0-2"

# 7. Usage errors (2) and bad input (3) name what is wrong.
expect_exit 2 "$COMMONLIGHT" track "$TMP/photos" --tag-size 0.08
expect_text "--calib" "$TMP/err"
expect_exit 2 "$COMMONLIGHT" track "$TMP/photos" --calib "$SRC/data/scenes/desk/calib.yaml"
expect_text "--tag-size" "$TMP/err"
expect_exit 2 "$COMMONLIGHT" track "$SAMPLE" --family tag99h99
expect_text "tag99h99" "$TMP/err"
expect_exit 2 "$COMMONLIGHT" track "$SAMPLE" --decimate 0.5
expect_exit 3 "$COMMONLIGHT" track "$TMP/nothing-here" --tag-size 0.08 --calib "$SRC/data/scenes/desk/calib.yaml"
expect_text "nothing-here" "$TMP/err"
mkdir "$TMP/empty"
expect_exit 3 "$COMMONLIGHT" track "$TMP/empty" --tag-size 0.08 --calib "$SRC/data/scenes/desk/calib.yaml"
expect_text "empty" "$TMP/err"
echo "track: ok"
