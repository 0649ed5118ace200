#!/usr/bin/env bash
# A camera that disconnects mid-stream ends the recording with a device error naming it (exit 4);
# the recorder closes cleanly and the sequence holds every frame received.
source "$(dirname "$0")/lib.sh"

uri="replay:$SAMPLE?rate=max&fault_disconnect_after=10"
expect_exit 4 "$COMMONLIGHT" record --camera "$uri" --out "$TMP/rec" --sync
expect_text "disconnected" "$TMP/err"
expect_text "replay:" "$TMP/err"
[[ $(rows "$TMP/rec/cam0/data.csv") == 10 ]] || fail "expected the 10 frames before the disconnect"
expect_exit 0 "$COMMONLIGHT" play "$TMP/rec" --sync
expect_text "played 10 of 10 frames" "$TMP/out"

# Frames dropped at the "device" are counted as such, from the gaps in the sequence numbers:
# every 4th frame is dropped, but a drop at the very end leaves no gap behind it.
dropped=$((SAMPLE_FRAMES / 4))
trailing=$(( SAMPLE_FRAMES % 4 == 0 ? 1 : 0 ))
expect_exit 0 "$COMMONLIGHT" record --camera "replay:$SAMPLE?rate=max&fault_drop_every=4" --out "$TMP/drops" --sync
expect_text "recorded $((SAMPLE_FRAMES - dropped)) frames" "$TMP/out"
expect_text "at the device $((dropped - trailing))," "$TMP/out"
echo PASS
