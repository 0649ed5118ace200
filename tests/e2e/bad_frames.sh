#!/usr/bin/env bash
# Corrupt, truncated and missing frame files: each frame gets status Corrupt, playback goes on,
# the count is reported, a warning names each file, and play exits 3.
source "$(dirname "$0")/lib.sh"

copy_sample "$TMP/seq"
truncated=$(frame_file "$TMP/seq" 10)
garbage=$(frame_file "$TMP/seq" 20)
missing=$(frame_file "$TMP/seq" 30)
head -c 2000 "$truncated" > "$TMP/cut" && mv "$TMP/cut" "$truncated"
echo "not an image" > "$garbage"
rm "$missing"

expect_exit 3 "$COMMONLIGHT" play "$TMP/seq" --sync --metrics "$TMP/m.json"
expect_text "played $SAMPLE_FRAMES of $SAMPLE_FRAMES frames" "$TMP/out"
expect_text "(3 corrupt)" "$TMP/out"
expect_text "$(basename "$truncated")" "$TMP/err"
expect_text "$(basename "$garbage")" "$TMP/err"
expect_text "$(basename "$missing")" "$TMP/err"
expect_text "3 frames could not be decoded" "$TMP/err"
[[ $(json_get "$TMP/m.json" corrupt_frames) == 3 ]] || fail "metrics corrupt_frames"
[[ $(json_get "$TMP/m.json" frames) == "$SAMPLE_FRAMES" ]] || fail "metrics frames"
echo PASS
