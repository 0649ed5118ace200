#!/usr/bin/env bash
# kill -9 during record leaves a sequence that play reads: every listed frame is complete.
source "$(dirname "$0")/lib.sh"

"$COMMONLIGHT" record --camera "replay:$SAMPLE?loop=1&speed=4" --out "$TMP/rec" >"$TMP/out" 2>"$TMP/err" &
pid=$!
wait_for_rows "$TMP/rec" 20
kill -9 "$pid"
wait "$pid" 2>/dev/null || true
n=$(rows "$TMP/rec/cam0/data.csv")
[[ $n -ge 20 ]] || fail "recorder too slow: $n frames"
# Every row is whole and names a complete file.
grep -v '^#' "$TMP/rec/cam0/data.csv" | while IFS=, read -r ts name; do
    [[ "$name" == "$ts.jpg" ]] || fail "bad row: $ts,$name"
    [[ -s "$TMP/rec/cam0/data/$name" ]] || fail "listed file missing: $name"
done
expect_exit 0 "$COMMONLIGHT" play "$TMP/rec" --sync
expect_text "played $n of $n frames" "$TMP/out"
expect_text "(0 corrupt)" "$TMP/out"
echo PASS
