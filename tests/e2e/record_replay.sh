#!/usr/bin/env bash
# Recording a replayed sequence and replaying the recording is bit-identical.
source "$(dirname "$0")/lib.sh"

expect_exit 0 "$COMMONLIGHT" record --camera "replay:$SAMPLE?rate=max" --out "$TMP/rec" --sync
expect_text "recorded $SAMPLE_FRAMES frames" "$TMP/out"
diff <(grep -v '^#' "$SAMPLE/cam0/data.csv") <(grep -v '^#' "$TMP/rec/cam0/data.csv") || fail "data.csv differs"
for i in $(seq 0 $((SAMPLE_FRAMES - 1))); do
    cmp "$(frame_file "$SAMPLE" "$i")" "$(frame_file "$TMP/rec" "$i")" || fail "frame $i differs"
done
# Exposure, gain and sequence numbers survive too.
diff <(grep -v '^#' "$SAMPLE/cam0/meta.csv") <(grep -v '^#' "$TMP/rec/cam0/meta.csv") || fail "meta.csv differs"
expect_exit 0 "$COMMONLIGHT" play "$TMP/rec" --sync
expect_text "played $SAMPLE_FRAMES of $SAMPLE_FRAMES frames" "$TMP/out"

# --frames stops early; an existing sequence is never overwritten.
expect_exit 0 "$COMMONLIGHT" record --camera "replay:$SAMPLE?rate=max" --out "$TMP/few" --sync --frames 7
[[ $(rows "$TMP/few/cam0/data.csv") == 7 ]] || fail "--frames 7"
expect_exit 3 "$COMMONLIGHT" record --camera "replay:$SAMPLE?rate=max" --out "$TMP/few" --sync --frames 7
expect_text "refusing to overwrite" "$TMP/err"
[[ $(rows "$TMP/few/cam0/data.csv") == 7 ]] || fail "the existing sequence was touched"

# Issue 14: --frames N --sync records N consecutive frames and loses none; the frames the replay
# made after the stop are not counted as dropped (they were, now and then, as "replaced in the
# mailbox"). Several runs: the frame made after the stop comes or not by timing.
for run in 1 2 3 4 5; do
    rm -rf "$TMP/honest"
    expect_exit 0 "$COMMONLIGHT" record --camera "replay:$SAMPLE?rate=max" --out "$TMP/honest" --sync --frames 5
    [[ $(rows "$TMP/honest/cam0/data.csv") == 5 ]] || fail "--frames 5, run $run"
    expect_text "dropped   0 (at the device 0, no free buffer 0, replaced in the mailbox 0)" "$TMP/out"
done
echo PASS
