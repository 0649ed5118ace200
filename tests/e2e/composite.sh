#!/usr/bin/env bash
# play composites the bundled sample: the frames, the MP4 and the side-by-side picture are
# written, the composite matches the path-traced ground truth (groundtruth/composite, rendered by
# mocks/sim, which shares no code with lighting/ or render/) within stated bounds, --sync output is
# byte-identical between runs, lighting on beats lighting off, and the bad-input cases.
source "$(dirname "$0")/lib.sh"

# 1. The whole pipeline, every frame, twice.
expect_exit 0 "$COMMONLIGHT" play "$SAMPLE" --sync --out "$TMP/a" --video "$TMP/a.mp4" --side-by-side "$TMP/sbs.png" \
    --metrics "$TMP/a.json"
expect_text "composite against ground truth" "$TMP/out"
[[ $(ls "$TMP/a" | wc -l) == "$SAMPLE_FRAMES" ]] || fail "expected $SAMPLE_FRAMES composited frames, got $(ls "$TMP/a" | wc -l)"
[[ -s "$TMP/a.mp4" && $(head -c 8 "$TMP/a.mp4" | tail -c 4) == "ftyp" ]] || fail "no MP4 written"
[[ -s "$TMP/sbs.png" ]] || fail "no side-by-side picture"
# Measured on this sample: PSNR 40.2 dB, linear RMSE 0.60 (frame) and 1.31 (masks/changed);
# asserted with margin.
python3 - "$TMP/a.json" <<'PY'
import json, sys
m = json.load(open(sys.argv[1]))
e = m["composite_error"]
assert e["frames"] == m["frames"], e
assert e["psnr_db"] > 38.0, e
assert e["rmse_linear_changed"] < 2.0, e
assert e["changed_pixels"] > 100000, e
c = m["compositor"]
assert c["frames"] == m["frames"], c
assert c["lighting_lag_frames"]["max"] == 0, c  # --sync: every frame composited with its own lighting
assert "composite" in m["stages_ms"], m["stages_ms"]
PY
expect_exit 0 "$COMMONLIGHT" play "$SAMPLE" --sync --out "$TMP/b" --metrics "$TMP/b.json"
for f in "$TMP"/a/*.png; do
    cmp -s "$f" "$TMP/b/$(basename "$f")" || fail "--sync is not deterministic: $(basename "$f") differs between runs"
done

# 2. Lighting off: the virtual objects get no estimated light and the real scene no shadows; the
# composite is measurably further from the truth.
expect_exit 0 "$COMMONLIGHT" play "$SAMPLE" --sync --no-lighting --metrics "$TMP/off.json"
python3 - "$TMP/a.json" "$TMP/off.json" <<'PY'
import json, sys
on = json.load(open(sys.argv[1]))["composite_error"]
off = json.load(open(sys.argv[2]))["composite_error"]
assert on["psnr_db"] > off["psnr_db"] + 2.0, (on, off)
assert on["rmse_linear_changed"] < 0.6 * off["rmse_linear_changed"], (on, off)
PY

# 3. Bad input: an MP4 that cannot be written (exit 3 before any work), a window without a display
# (exit 4 naming DISPLAY).
expect_exit 3 "$COMMONLIGHT" play "$SAMPLE" --sync --video "$TMP/missing/dir/x.mp4"
expect_text "x.mp4" "$TMP/err"
[[ ! -e "$TMP/missing" ]] || fail "a folder was made for the unwritable video"
# A side-by-side picture that cannot be written: exit 3 naming it, before any frame is played.
expect_exit 3 "$COMMONLIGHT" play "$SAMPLE" --sync --side-by-side "$TMP/missing/dir/sbs.png"
expect_text "sbs.png" "$TMP/err"
expect_text "does not exist" "$TMP/err"
expect_exit 3 "$COMMONLIGHT" play "$SAMPLE" --sync --side-by-side "$TMP/sbs.unknown-format"
expect_text "no image writer" "$TMP/err"
expect_exit 4 env -u DISPLAY -u WAYLAND_DISPLAY "$COMMONLIGHT" play "$SAMPLE" --sync --window
expect_text "DISPLAY" "$TMP/err"
echo PASS
