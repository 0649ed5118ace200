#!/usr/bin/env bash
# -q means errors only, for every subcommand (docs/cli.md): no summary, no progress message; a
# subcommand's product (track's CSV on standard output) is still written; errors still print.
source "$(dirname "$0")/lib.sh"

header='image,timestamp_ns,tag_id,c0x,c0y,c1x,c1y,c2x,c2y,c3x,c3y,tx,ty,tz,qw,qx,qy,qz,status,pose_timestamp_ns,ambiguity_ratio,alt_tx,alt_ty,alt_tz,alt_qw,alt_qx,alt_qy,alt_qz,verified'

# track: without -q a summary on stderr; with -q nothing but the CSV.
expect_exit 0 "$COMMONLIGHT" track "$SAMPLE" --out "$TMP/a.csv"
expect_text "tracked $SAMPLE_FRAMES frames" "$TMP/err"
expect_exit 0 "$COMMONLIGHT" -q track "$SAMPLE" --out "$TMP/b.csv"
[[ ! -s "$TMP/out" && ! -s "$TMP/err" ]] || { cat "$TMP/out" "$TMP/err"; fail "track -q printed something"; }
cmp -s "$TMP/a.csv" "$TMP/b.csv" || fail "track -q wrote another CSV"
expect_exit 0 "$COMMONLIGHT" -q track "$SAMPLE"
[[ ! -s "$TMP/err" ]] || { cat "$TMP/err"; fail "track -q printed on stderr"; }
[[ $(head -1 "$TMP/out") == "$header" ]] || fail "track -q lost the CSV on stdout"
# An error is still an error under -q.
expect_exit 3 "$COMMONLIGHT" -q track "$TMP/missing" --calib "$SRC/data/scenes/desk/calib.yaml" --tag-size 0.08
[[ -s "$TMP/err" ]] || fail "track -q hid an error"

# sim and play: their progress and summaries.
scene="$SRC/data/scenes/hard/scene.yaml"
expect_exit 0 "$COMMONLIGHT" -q sim --scene "$scene" --trajectory "$SRC/data/scenes/hard/fronto.yaml" --out "$TMP/seq" \
    --frames 1 --spp 1 --no-radiance
[[ ! -s "$TMP/out" && ! -s "$TMP/err" ]] || { cat "$TMP/out" "$TMP/err"; fail "sim -q printed something"; }
[[ $(rows "$TMP/seq/cam0/data.csv") == 1 ]] || fail "sim -q wrote no frame"
expect_exit 0 "$COMMONLIGHT" sim --scene "$scene" --trajectory "$SRC/data/scenes/hard/fronto.yaml" --out "$TMP/seq2" \
    --frames 1 --spp 1 --no-radiance
expect_text "wrote 1 frames" "$TMP/out"
expect_exit 0 "$COMMONLIGHT" -q play "$TMP/seq" --sync
[[ ! -s "$TMP/out" && ! -s "$TMP/err" ]] || { cat "$TMP/out" "$TMP/err"; fail "play -q printed something"; }
echo "ok"
