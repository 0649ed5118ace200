#!/usr/bin/env bash
# The bundled scenes render: one frame of the desk and of every hard case (1 spp), each a
# readable sequence with ground truth that play accepts. Bad sim input exits 2 or 3.
source "$(dirname "$0")/lib.sh"

scenes="$SRC/data/scenes"
scenes_tmp="$TMP/scenes"
mkdir -p "$scenes_tmp"
cp "$scenes/desk/calib.yaml" "$scenes_tmp/"
render() {  # name, options...
    local name=$1; shift
    expect_exit 0 "$COMMONLIGHT" sim --out "$TMP/$name" --frames 1 --spp 1 --no-radiance "$@"
    expect_text "wrote 1 frames" "$TMP/out"
    expect_exit 0 "$COMMONLIGHT" play "$TMP/$name" --sync
    expect_text "played 1 of 1 frames" "$TMP/out"
    [[ $(rows "$TMP/$name/groundtruth/cam_poses.csv") == 1 ]] || fail "$name: cam_poses.csv"
}
render desk --scene "$scenes/desk/scene.yaml" --trajectory "$scenes/desk/trajectory.yaml" --format jpeg
[[ -f "$TMP/desk/groundtruth/composite/0.jpg" ]] || fail "desk: composite frame"
[[ -f "$TMP/desk/groundtruth/masks/changed/0.png" ]] || fail "desk: changed mask"
for case in small fronto oblique75 occluded; do
    render "hard-$case" --scene "$scenes/hard/scene.yaml" --trajectory "$scenes/hard/$case.yaml"
done
render hard-blur --scene "$scenes/hard/scene.yaml" --trajectory "$scenes/hard/blur.yaml" --motion-blur --exposure-us 20000
render hard-wide --scene "$scenes/hard/scene.yaml" --trajectory "$scenes/hard/wide.yaml" --calib "$scenes/hard/calib_wide.yaml"

# Bad input.
expect_exit 2 "$COMMONLIGHT" sim --scene "$scenes/desk/scene.yaml" --trajectory "$scenes/desk/trajectory.yaml" \
    --out "$TMP/x" --sensor bits=7
expect_text "bits" "$TMP/err"
printf 'orbit: {target: [0, 0, 0], radius: 1}\n' > "$TMP/bad.yaml"
expect_exit 3 "$COMMONLIGHT" sim --scene "$scenes/desk/scene.yaml" --trajectory "$TMP/bad.yaml" --out "$TMP/y"
expect_text "bad.yaml" "$TMP/err"
# A sensor section in the scene: used, and validated with file, line and key.
sed 's/^camera: calib.yaml/camera: calib.yaml\nsensor: {bits: 12, exposure_us: 5000}/' "$scenes/desk/scene.yaml" > "$scenes_tmp/scene.yaml"
expect_exit 0 "$COMMONLIGHT" sim --scene "$scenes_tmp/scene.yaml" --trajectory "$scenes/desk/trajectory.yaml" \
    --out "$TMP/sensor" --frames 1 --spp 1 --no-composite
grep -q "^0,0,5000,1,ok$" "$TMP/sensor/cam0/meta.csv" || fail "exposure from the scene's sensor"
grep -q "bits: 12" "$TMP/sensor/groundtruth/sensor.yaml" || fail "bits from the scene's sensor"
sed -i 's/bits: 12/bits: 7/' "$scenes_tmp/scene.yaml"
expect_exit 3 "$COMMONLIGHT" sim --scene "$scenes_tmp/scene.yaml" --trajectory "$scenes/desk/trajectory.yaml" \
    --out "$TMP/sensor7" --frames 1
expect_text "scene.yaml:" "$TMP/err"
expect_text "sensor.bits" "$TMP/err"
expect_exit 3 "$COMMONLIGHT" sim --scene "$scenes/desk/scene.yaml" --trajectory "$scenes/desk/trajectory.yaml" \
    --out "$TMP/desk" --frames 1
expect_text "refusing to overwrite" "$TMP/err"
echo PASS
