#!/usr/bin/env bash
# commonlight calibrate-response on an exposure bracket the simulated camera renders (sRGB sensor,
# 7 exposures x2 apart, a small desk view): the curve written is close to sRGB and far from linear;
# bad brackets are errors naming the file (exit 3).
source "$(dirname "$0")/lib.sh"

cat >"$TMP/calib.yaml" <<'YAML'
%YAML:1.0
---
image_width: 160
image_height: 120
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 131.25, 0., 79.5, 0., 131.25, 59.5, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ 0., 0., 0., 0., 0. ]
YAML
mkdir -p "$TMP/bracket"
for e in 1000 2000 4000 8000 16000 32000 64000; do
    expect_exit 0 "$COMMONLIGHT" sim --scene "$SRC/data/scenes/desk/scene.yaml" --trajectory "$SRC/data/scenes/desk/trajectory.yaml" \
        --calib "$TMP/calib.yaml" --out "$TMP/s$e" --frames 1 --spp 8 --exposure-us "$e" --no-composite --no-masks --no-radiance
    cp "$TMP/s$e/cam0/data/0.png" "$TMP/bracket/e$e.png"
    echo "e$e.png,$e" >>"$TMP/bracket/exposures.csv"
done

expect_exit 0 "$COMMONLIGHT" calibrate-response --images "$TMP/bracket" --out "$TMP/response.yaml"
expect_text "closest model" "$TMP/out"
# The recovered curve: sRGB within a few percent, linear far off (the summary line).
python3 - "$TMP/out" <<'PY'
import re, sys
text = open(sys.argv[1]).read()
m = re.search(r"srgb RMS ([0-9.]+)%, linear RMS ([0-9.]+)%", text)
assert m, text
srgb, linear = float(m.group(1)), float(m.group(2))
assert srgb < 5.0, f"srgb RMS {srgb}%"
assert linear > 20.0, f"linear RMS {linear}%"
PY
# The file reads back as a response: play and track accept it (--response FILE).
expect_text "type: table" "$TMP/response.yaml"
expect_exit 0 "$COMMONLIGHT" track "$SAMPLE" --out "$TMP/poses.csv" --response "$TMP/response.yaml"

# Bad brackets: one image, equal exposures, a missing file, a non-numeric exposure, no exposures.csv.
mkdir -p "$TMP/bad1" && cp "$TMP/bracket/e1000.png" "$TMP/bad1/" && echo "e1000.png,1000" >"$TMP/bad1/exposures.csv"
expect_exit 3 "$COMMONLIGHT" calibrate-response --images "$TMP/bad1" --out "$TMP/r.yaml"
expect_text "at least 2 images" "$TMP/err"
mkdir -p "$TMP/bad2" && cp "$TMP/bracket/e1000.png" "$TMP/bracket/e2000.png" "$TMP/bad2/"
printf 'e1000.png,1000\ne2000.png,1000\n' >"$TMP/bad2/exposures.csv"
expect_exit 3 "$COMMONLIGHT" calibrate-response --images "$TMP/bad2" --out "$TMP/r.yaml"
expect_text "same exposure" "$TMP/err"
printf 'e1000.png,1000\nmissing.png,2000\n' >"$TMP/bad2/exposures.csv"
expect_exit 3 "$COMMONLIGHT" calibrate-response --images "$TMP/bad2" --out "$TMP/r.yaml"
expect_text "missing.png" "$TMP/err"
printf 'e1000.png,1000\ne2000.png,fast\n' >"$TMP/bad2/exposures.csv"
expect_exit 3 "$COMMONLIGHT" calibrate-response --images "$TMP/bad2" --out "$TMP/r.yaml"
expect_text "exposures.csv:2" "$TMP/err"
mkdir -p "$TMP/bad3"
expect_exit 3 "$COMMONLIGHT" calibrate-response --images "$TMP/bad3" --out "$TMP/r.yaml"
expect_text "exposures.csv" "$TMP/err"
expect_exit 2 "$COMMONLIGHT" calibrate-response --out "$TMP/r.yaml"
echo "calibrate-response: ok"
