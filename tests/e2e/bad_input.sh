#!/usr/bin/env bash
# Malformed files give exit 3 and a message naming the file and the line or key.
source "$(dirname "$0")/lib.sh"

fresh() { rm -rf "$TMP/seq"; copy_sample "$TMP/seq"; }

# Duplicate timestamp in data.csv.
fresh
line3=$(sed -n 3p "$TMP/seq/cam0/data.csv")
sed -i "4s/.*/$line3/" "$TMP/seq/cam0/data.csv"
expect_exit 3 "$COMMONLIGHT" play "$TMP/seq" --sync
expect_text "data.csv:4: duplicate timestamp" "$TMP/err"

# Non-monotonic timestamps.
fresh
sed -i '5{h;d};6{G}' "$TMP/seq/cam0/data.csv"
expect_exit 3 "$COMMONLIGHT" play "$TMP/seq" --sync
expect_text "data.csv:6: decreasing timestamp" "$TMP/err"

# Truncated data.csv (a row cut in the middle).
fresh
printf '1800000000000000000' >> "$TMP/seq/cam0/data.csv"
expect_exit 3 "$COMMONLIGHT" play "$TMP/seq" --sync
expect_text "data.csv:$((SAMPLE_FRAMES + 2)): expected 2 columns, found 1 (the file looks truncated)" "$TMP/err"

# Malformed sensor.yaml.
fresh
sed -i 's/^resolution: .*/resolution: [640]/' "$TMP/seq/cam0/sensor.yaml"
expect_exit 3 "$COMMONLIGHT" play "$TMP/seq" --sync
expect_text "sensor.yaml:" "$TMP/err"
expect_text "key 'resolution': expected 2 numbers, found 1" "$TMP/err"

# Malformed scene YAML: a typo in a key.
fresh
sed -i 's/world_from_tag: {t:/world_from_tag: {tt:/' "$TMP/seq/scene.yaml"
expect_exit 3 "$COMMONLIGHT" play "$TMP/seq" --sync
expect_text "scene.yaml:" "$TMP/err"
expect_text "unknown key" "$TMP/err"
expect_text "tags.items[0].world_from_tag.tt" "$TMP/err"

# Scene YAML syntax error, given with --scene.
printf 'tags:\n  family: tag36h11\n  items: [\n' > "$TMP/broken.yaml"
expect_exit 3 "$COMMONLIGHT" play "$SAMPLE" --sync --scene "$TMP/broken.yaml"
expect_text "broken.yaml:" "$TMP/err"

# Malformed calibration for record --calib.
cat > "$TMP/calib.yaml" <<'YAML'
%YAML:1.0
image_width: 640
image_height: 480
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 525., 0., 319.5, 0., 525., 239.5, 0., 0. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ 0., 0., 0., 0., 0. ]
YAML
expect_exit 3 "$COMMONLIGHT" record --camera "replay:$SAMPLE?rate=max" --out "$TMP/rec" --calib "$TMP/calib.yaml" --frames 2
expect_text "calib.yaml:" "$TMP/err"
expect_text "camera_matrix" "$TMP/err"
[[ ! -e "$TMP/rec/cam0/data.csv" ]] || fail "a failed record must not create a sequence"

# Issue 14: a calibration matrix with rows, cols and dt but no data (it aborted with
# YAML::InvalidNode): exit 3 and the key, from `track --calib`.
cat > "$TMP/nodata.yaml" <<'YAML'
%YAML:1.0
image_width: 640
image_height: 480
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 525., 0., 319.5, 0., 525., 239.5, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
YAML
expect_exit 3 "$COMMONLIGHT" track "$SAMPLE" --calib "$TMP/nodata.yaml" --tag-size 0.16 --out "$TMP/poses.csv"
expect_text "nodata.yaml:" "$TMP/err"
expect_text "key 'distortion_coefficients.data': missing" "$TMP/err"
grep -q "terminate called" "$TMP/err" && fail "track aborted on a calibration without data"

# Missing sequence.
expect_exit 3 "$COMMONLIGHT" play "$TMP/does-not-exist"
expect_text "does-not-exist: no such sequence folder" "$TMP/err"
echo PASS
