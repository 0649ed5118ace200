#!/usr/bin/env bash
# What scripts/soak relies on: live's --metrics-interval lines (fps, lighting lag, GL object
# counts) with --move-object, and `commonlight plot` (a CSV's columns as a PNG; bad input named).
source "$(dirname "$0")/lib.sh"
SAMPLE="$SRC/data/sample"

expect_exit 0 "$COMMONLIGHT" live --camera "replay:$SAMPLE?loop=1" --scene "$SAMPLE/scene.yaml" --headless --composite \
    --frames 60 --settle 0 --timeout 120 --move-object --metrics-interval 0.5 --out "$TMP/live"
grep -q '^metrics: t_s=' "$TMP/out" || fail "live --metrics-interval printed no metrics line"
python3 - "$TMP/out" <<'PY'
import sys
lines = [l.split()[1:] for l in open(sys.argv[1]) if l.startswith("metrics: ")]
assert lines, "no metrics lines"
for fields in lines:
    kv = dict(f.split("=", 1) for f in fields)
    for key in ("t_s", "frames", "fps", "lag_ms_max", "lighting_version", "gl_objects", "gl_textures", "gl_programs"):
        assert key in kv, (key, kv)
    assert float(kv["fps"]) >= 0 and int(kv["gl_objects"]) > 0, kv
    assert int(kv["gl_objects"]) == sum(int(kv[k]) for k in kv if k.startswith("gl_") and k != "gl_objects"), kv
PY
[[ $(json_get "$TMP/live/metrics.json" frames) == 60 ]] || fail "expected 60 frames"

# plot: two panels against t_s.
printf 't_s,rss_mb,fds\n0,100.5,6\n10,101.0,6\n20,101.2,7\n' > "$TMP/s.csv"
expect_exit 0 "$COMMONLIGHT" plot "$TMP/s.csv" --out "$TMP/s.png" --title soak
python3 "$SRC/tests/e2e/pngcheck.py" "$TMP/s.png" "all=0,0,-1,-1,True" > "$TMP/png.txt" || fail "plot wrote no readable PNG"
(( $(awk '{print $2}' "$TMP/png.txt") > 10000 )) || fail "the plot is too small: $(cat "$TMP/png.txt")"
# Bad input: a column that is not there, a missing file, a truncated row.
expect_exit 3 "$COMMONLIGHT" plot "$TMP/s.csv" --out "$TMP/t.png" --columns rss_mb,nosuch
expect_text "nosuch" "$TMP/err"
expect_exit 3 "$COMMONLIGHT" plot "$TMP/missing.csv" --out "$TMP/t.png"
expect_text "missing.csv" "$TMP/err"
printf 't_s,rss_mb\n0,1\n10\n' > "$TMP/bad.csv"
expect_exit 3 "$COMMONLIGHT" plot "$TMP/bad.csv" --out "$TMP/t.png"
expect_text "bad.csv" "$TMP/err"
echo "soak_tools: ok"
