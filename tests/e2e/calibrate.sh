#!/usr/bin/env bash
# commonlight calibrate: --help, usage errors (exit 2), bad input (exit 3), and a calibration from an
# AprilGrid rendered by `commonlight sim` (9 views, 4 spp), as a sequence and as an image folder
# with a corrupt image among the good ones.
source "$(dirname "$0")/lib.sh"

BOARD="aprilgrid:6x6:0.04:0.3"

# --help names the options and the board specs.
expect_exit 0 "$COMMONLIGHT" calibrate --help
expect_text "--board" "$TMP/out"
expect_text "aprilgrid:COLSxROWS:TAG_M:SPACING_RATIO" "$TMP/out"
expect_text "--sequence" "$TMP/out"

# Usage errors: a board spec that does not parse names the spec and the field; exactly one input.
mkdir -p "$TMP/empty"
expect_exit 2 "$COMMONLIGHT" calibrate --images "$TMP/empty" --board chessboard:9x6 --out "$TMP/c.yaml"
expect_text "board spec 'chessboard:9x6': expected chessboard:COLSxROWS:SQUARE_M (3 fields), found 2 fields" "$TMP/err"
expect_exit 2 "$COMMONLIGHT" calibrate --images "$TMP/empty" --board aprilgrid:6x6:0.04:zero --out "$TMP/c.yaml"
expect_text "SPACING_RATIO 'zero' is not a number" "$TMP/err"
expect_exit 2 "$COMMONLIGHT" calibrate --images "$TMP/empty" --board hexagons:3x3:1 --out "$TMP/c.yaml"
expect_text "unknown board type 'hexagons'" "$TMP/err"
expect_exit 2 "$COMMONLIGHT" calibrate --board "$BOARD" --out "$TMP/c.yaml"
expect_text "give exactly one of --images DIR and --sequence SEQ" "$TMP/err"
expect_exit 2 "$COMMONLIGHT" calibrate --images "$TMP/empty" --sequence "$TMP/empty" --board "$BOARD" --out "$TMP/c.yaml"
expect_exit 2 "$COMMONLIGHT" calibrate --images "$TMP/empty" --board "$BOARD"

# Bad input: a missing folder or sequence, a folder without images, an output folder that is missing.
expect_exit 3 "$COMMONLIGHT" calibrate --images "$TMP/does-not-exist" --board "$BOARD" --out "$TMP/c.yaml"
expect_text "does-not-exist: no such folder (--images)" "$TMP/err"
expect_exit 3 "$COMMONLIGHT" calibrate --sequence "$TMP/no-sequence" --board "$BOARD" --out "$TMP/c.yaml"
expect_text "no-sequence" "$TMP/err"
expect_exit 3 "$COMMONLIGHT" calibrate --images "$TMP/empty" --board "$BOARD" --out "$TMP/c.yaml"
expect_text "no .png, .jpg or .jpeg images" "$TMP/err"
expect_exit 3 "$COMMONLIGHT" calibrate --images "$TMP/empty" --board "$BOARD" --out "$TMP/missing/c.yaml"
expect_text "does not exist (--out)" "$TMP/err"

# Render the AprilGrid: 36 tags on a white sheet on a grey wall, seen from 9 places.
python3 - "$TMP/scene.yaml" <<'PY'
import sys
cols, rows, t, ratio = 6, 6, 0.04, 0.3
pitch = (1 + ratio) * t
w = cols * pitch - ratio * t
lines = ["tags:", "  family: tag36h11", "  items:"]
for r in range(rows):          # Kalibr's ids: row-major from the bottom-left tag; the board faces -y
    for c in range(cols):
        x = -w / 2 + c * pitch + t / 2
        z = 0.75 - w / 2 + r * pitch + t / 2
        lines.append(f"    - {{id: {r * cols + c}, size: {t}, world_from_tag: {{t: [{x:.6f}, 0, {z:.6f}], rpy_deg: [90, 0, 0]}}}}")
lines += ["real:",
          f"  - {{name: sheet, plane: {{size: [{w + 2 * t:.4f}, {w + 2 * t:.4f}]}}, world_from_object: {{t: [0, 0, 0.75], rpy_deg: [90, 0, 0]}}, albedo: [0.8, 0.8, 0.8]}}",
          "  - {name: wall, plane: {size: [4, 3]}, world_from_object: {t: [0, 0.05, 1.0], rpy_deg: [90, 0, 0]}, albedo: [0.3, 0.3, 0.3]}",
          "lights:",
          "  - {name: sun, directional: {direction: [0.2, 1, -0.6]}, irradiance: [3, 3, 3]}",
          "  - {name: sky, distant: {directions: 16}, radiance: [0.3, 0.3, 0.3]}"]
open(sys.argv[1], "w").write("\n".join(lines) + "\n")
PY
cat > "$TMP/calib.yaml" <<'YAML'
%YAML:1.0
---
image_width: 640
image_height: 480
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 600., 0., 322.4, 0., 601.5, 236.7, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -0.2, 0.05, 0.001, -0.0005, 0. ]
YAML
cat > "$TMP/trajectory.yaml" <<'YAML'
rate_hz: 1
keyframes:
  - {t: 0, eye: [0, -0.55, 0.75], target: [0, 0, 0.75]}
  - {t: 1, eye: [0.35, -0.45, 0.75], target: [0, 0, 0.75]}
  - {t: 2, eye: [-0.35, -0.45, 0.75], target: [0, 0, 0.75]}
  - {t: 3, eye: [0, -0.45, 1.1], target: [0, 0, 0.75]}
  - {t: 4, eye: [0, -0.45, 0.4], target: [0, 0, 0.75]}
  - {t: 5, eye: [0.2, -0.5, 0.95], target: [0.12, 0, 0.62]}
  - {t: 6, eye: [-0.2, -0.5, 0.55], target: [-0.12, 0, 0.88]}
  - {t: 7, eye: [0.25, -0.45, 0.5], target: [-0.12, 0, 0.9]}
  - {t: 8, eye: [-0.25, -0.45, 1.0], target: [0.12, 0, 0.6]}
YAML
expect_exit 0 "$COMMONLIGHT" sim --scene "$TMP/scene.yaml" --trajectory "$TMP/trajectory.yaml" --calib "$TMP/calib.yaml" \
    --out "$TMP/seq" --spp 4 --max-depth 2 --no-composite --no-radiance
expect_text "wrote 9 frames" "$TMP/out"

# check_calib FILE: the intrinsics within 1% and k1 within 0.02 of the truth.
check_calib() {
    python3 - "$1" <<'PY' || fail "calibration in $1 is off"
import re, sys
text = open(sys.argv[1]).read()
def matrix(key):
    m = re.search(key + r": !!opencv-matrix\s+rows: \d+\s+cols: \d+\s+dt: d\s+data: \[([^\]]*)\]", text)
    return [float(v) for v in m.group(1).split(",")]
k = matrix("camera_matrix")
d = matrix("distortion_coefficients")
fx, cx, fy, cy, k1 = k[0], k[2], k[4], k[5], d[0]
print(f"fx {fx:.2f} fy {fy:.2f} cx {cx:.2f} cy {cy:.2f} k1 {k1:.4f}")
ok = all(abs(a - b) <= 0.01 * b for a, b in [(fx, 600.0), (fy, 601.5), (cx, 322.4), (cy, 236.7)])
sys.exit(0 if ok and abs(k1 + 0.2) < 0.02 else 1)
PY
}

# From the sequence.
expect_exit 0 "$COMMONLIGHT" calibrate --sequence "$TMP/seq" --board "$BOARD" --out "$TMP/seq.yaml"
expect_text "found the board in 9 of 9 images" "$TMP/out"
expect_text "wrote $TMP/seq.yaml" "$TMP/out"
for key in image_width image_height camera_matrix distortion_coefficients avg_reprojection_error \
    per_view_reprojection_errors std_deviations_intrinsics image_names rejected_views coverage; do
    expect_text "$key:" "$TMP/seq.yaml"
done
check_calib "$TMP/seq.yaml"

# From an image folder with a corrupt image and a text file among the frames: the corrupt one is
# skipped with a warning naming it and listed as rejected, the text file is not an image.
mkdir -p "$TMP/images"
cp "$TMP"/seq/cam0/data/*.png "$TMP/images/"
head -c 2000 "$TMP/images/0.png" > "$TMP/images/broken.png"
echo "not an image" > "$TMP/images/notes.txt"
expect_exit 0 "$COMMONLIGHT" calibrate --images "$TMP/images" --board "$BOARD" --out "$TMP/images.yaml"
expect_text "calibrating from 10 images" "$TMP/out"
expect_text "skipping $TMP/images/broken.png" "$TMP/err"
expect_text "1 unreadable image was skipped" "$TMP/err"
expect_text "image: \"broken.png\", reason: \"unreadable:" "$TMP/images.yaml"
check_calib "$TMP/images.yaml"

# An image of another size is an error naming it.
python3 - "$TMP/images/small.png" <<'PY'
import struct, sys, zlib
w, h = 320, 240
raw = b"".join(b"\x00" + bytes([128]) * w for _ in range(h))
chunk = lambda kind, data: struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)) + \
      chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
open(sys.argv[1], "wb").write(png)
PY
expect_exit 3 "$COMMONLIGHT" calibrate --images "$TMP/images" --board "$BOARD" --out "$TMP/x.yaml"
expect_text "small.png: image is 320x240 but 0.png is 640x480" "$TMP/err"
[[ ! -e "$TMP/x.yaml" ]] || fail "a failed calibration must not write its output"

# Fewer than 3 usable views.
mkdir -p "$TMP/two"
cp "$TMP/seq/cam0/data/0.png" "$TMP/seq/cam0/data/1000000000.png" "$TMP/two/"
cp "$TMP/images/broken.png" "$TMP/two/"
expect_exit 3 "$COMMONLIGHT" calibrate --images "$TMP/two" --board "$BOARD" --out "$TMP/x.yaml"
expect_text "only 2 usable views of the $BOARD board, at least 3 needed; rejected: broken.png (unreadable:" "$TMP/err"

# The wrong board: nothing found.
expect_exit 3 "$COMMONLIGHT" calibrate --sequence "$TMP/seq" --board chessboard:9x6:0.025 --out "$TMP/x.yaml"
expect_text "only 0 usable views" "$TMP/err"
echo PASS
