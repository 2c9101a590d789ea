#!/usr/bin/env bash
# Coverage-guided fuzzing (cargo-fuzz / libFuzzer) of the parsers, the decoder and CPR, the
# aircraft pipeline and the config loader: builds a seed corpus from the fixtures, then runs
# every target for SECONDS_PER_TARGET (default 10), one after the other. Exits non-zero if
# any target finds a crash (the input is saved under fuzz/artifacts/<target>/).
#
#   scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]
#
# Works on a stable toolchain: no sanitizer (safe Rust; libFuzzer still catches panics,
# aborts, timeouts and runaway memory), debug assertions and overflow checks on (-a).
# Needs `cargo install cargo-fuzz --locked`. Seeds (cut from the fixtures, plus the inputs of
# past findings in fuzz/regressions/<target>) go to fuzz/seeds/<target>, what the
# fuzzer learns to fuzz/corpus/<target> (both ignored by git and kept between runs).
# FUZZ_ARGS adds libFuzzer options, e.g. FUZZ_ARGS="-jobs=2 -workers=2".
set -euo pipefail
cd "$(dirname "$0")/.."

SECONDS_PER_TARGET="${1:-10}"
shift || true
ALL_TARGETS=(feed_beast feed_avr feed_lines decode_cpr pipeline config cluster_pack pace_fit)
if [ "$#" -gt 0 ]; then TARGETS=("$@"); else TARGETS=("${ALL_TARGETS[@]}"); fi

# The same flags for the build and every run (otherwise `cargo fuzz run` rebuilds).
FUZZ_FLAGS=(--sanitizer none --debug-assertions)

# ---- seeds ----------------------------------------------------------------------------
SEEDS=fuzz/seeds
FX=fixtures
rm -rf "$SEEDS"
for t in "${ALL_TARGETS[@]}"; do mkdir -p "$SEEDS/$t"; done
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT

# seed TARGET SELECTOR_BYTE NAME < data: one seed file, the selector byte then the data.
seed() {
    { printf "\\$(printf '%03o' "$2")"; cat; } > "$SEEDS/$1/$3"
}

# pieces NAME SPLIT_ARGS... < data: the data cut by `split` into $WORK/NAME.*
pieces() {
    local name="$1"
    shift
    split -a 3 "$@" - "$WORK/$name."
}

# Beast: the Toulouse sample in small and larger pieces (the parser resynchronises on cuts).
pieces beast-small -b 600 < "$FX/toulouse-sample.beast"
pieces beast-large -b 2100 < "$FX/toulouse-sample.beast"
# AVR: lines from the start and the middle of the LAX recording.
{ sed -n '1,400p' "$FX/lax-messages.avr.txt"; } | pieces avr -l 40
sed -n '100000,100400p' "$FX/lax-messages.avr.txt" | pieces avr-mid -l 80
# CSV, ISO time, JSON lines (the JSON flight: gate, take-off roll, climb, cruise).
pieces csv -l 60 < "$FX/us-short-flights.csv"
sed -n '1,800p' "$FX/pymodes-2015-03-03.txt" | pieces iso -l 50
{
    sed -n '1,60p' "$FX/afr34zg-cdg-tls.jsonl"
    sed -n '9000,9240p' "$FX/afr34zg-cdg-tls.jsonl"
    sed -n '30000,30240p' "$FX/afr34zg-cdg-tls.jsonl"
} | pieces jsonl -l 20

n=0
for f in "$WORK"/beast-small.*; do
    n=$((n + 1))
    seed feed_beast $((n % 7)) "beast-$n" < "$f"
    # decode_cpr: Beast (0), parity fixed (8) on every other seed, receiver (0x20).
    seed decode_cpr $(((n % 2) * 8 | 0x30)) "beast-$n" < "$f"
done
for f in "$WORK"/beast-large.*; do
    n=$((n + 1))
    # pipeline: Beast, each piece with another tracker (bits 4-7), with and without parity fix.
    seed pipeline $(((n % 12) << 4)) "beast-$n" < "$f"
    seed pipeline $(((n % 12) << 4 | 8)) "beast-fixed-$n" < "$f"
done
# Synthetic DF17 records (selector bits 0-2 = 5: 8 bytes a report, all from few addresses):
# any bytes will do as a start; the Beast pieces serve.
for f in "$WORK"/beast-small.*; do
    n=$((n + 1))
    seed pipeline $((5 | (n % 12) << 4)) "records-$n" < "$f"
    seed decode_cpr $((5 | 0x30)) "records-$n" < "$f"
done
for f in "$WORK"/avr.* "$WORK"/avr-mid.*; do
    n=$((n + 1))
    seed feed_avr $((n % 7)) "avr-$n" < "$f"
    seed decode_cpr $((1 | 0x10)) "avr-$n" < "$f"
done
for f in "$WORK"/avr-mid.*; do
    n=$((n + 1))
    seed pipeline $((1 | (n % 12) << 4)) "avr-$n" < "$f"
done
# feed_lines: selector % 3 is the format (0 CSV, 1 ISO, 2 JSON lines), selector / 3 the cuts.
for f in "$WORK"/csv.*; do
    n=$((n + 1))
    seed feed_lines $((3 * (n % 7))) "csv-$n" < "$f"
    seed decode_cpr $((2 | 0x10)) "csv-$n" < "$f"
    seed pipeline $((2 | (n % 12) << 4)) "csv-$n" < "$f"
done
for f in "$WORK"/iso.*; do
    n=$((n + 1))
    seed feed_lines $((1 + 3 * (n % 7))) "iso-$n" < "$f"
    seed decode_cpr 3 "iso-$n" < "$f"
done
for f in "$WORK"/jsonl.*; do
    n=$((n + 1))
    seed feed_lines $((2 + 3 * (n % 7))) "jsonl-$n" < "$f"
    seed decode_cpr $((4 | 0x10)) "jsonl-$n" < "$f"
    seed pipeline $((4 | (n % 12) << 4)) "jsonl-$n" < "$f"
done
# Lines past MAX_LINE_BYTES (16 KiB): `0xFF n` in a text target's input repeats the byte
# before it (n + 1) * 128 times, so these seeds are a few bytes each.
printf '#a\377\200\n*8D4840D6202CC371C32CE0576098;\n \377\200\n' | seed feed_avr 1 long-lines
printf '*8D\377\201\n1.5,8D4840D6202CC371C32CE0576098\n' | seed feed_lines 3 long-lines
# config: the documented defaults whole and table by table, and the scenario files.
cp config/default.toml "$SEEDS/config/default.toml"
csplit -s -z -f "$SEEDS/config/default-" config/default.toml '/^\[/' '{*}'
for f in "$FX"/scenarios/*.toml; do cp "$f" "$SEEDS/config/scenario-$(basename "$f")"; done

# Every input that once crashed a target (fuzz/regressions/<target>/, committed) runs first.
for t in "${ALL_TARGETS[@]}"; do
    mkdir -p "fuzz/corpus/$t"
    if [ -d "fuzz/regressions/$t" ]; then cp fuzz/regressions/"$t"/* "$SEEDS/$t/"; fi
done
echo "fuzz: seeds $(du -sh "$SEEDS" | cut -f1) ($(find "$SEEDS" -type f | wc -l) files)" >&2

# ---- build once, then run ---------------------------------------------------------------
# cargo-fuzz has no --locked: fetching with it first fails if fuzz/Cargo.lock is stale (it
# must keep the yanked deku 0.19.0 of the main lock), and the build then uses it as is.
cargo fetch --locked --manifest-path fuzz/Cargo.toml
cargo fuzz build "${FUZZ_FLAGS[@]}"

failed=()
for t in "${TARGETS[@]}"; do
    max_len=8192
    [ "$t" = config ] && max_len=16384
    echo "fuzz: $t for ${SECONDS_PER_TARGET}s" >&2
    # shellcheck disable=SC2086
    if ! cargo fuzz run "${FUZZ_FLAGS[@]}" "$t" "fuzz/corpus/$t" "$SEEDS/$t" -- \
        -max_total_time="$SECONDS_PER_TARGET" -max_len="$max_len" -timeout=20 \
        -rss_limit_mb=2048 -print_final_stats=1 ${FUZZ_ARGS:-}; then
        failed+=("$t")
    fi
done

if [ "${#failed[@]}" -gt 0 ]; then
    echo "fuzz: FAILED: ${failed[*]} (inputs in fuzz/artifacts/<target>/; reproduce with" \
        "cargo fuzz run ${FUZZ_FLAGS[*]} <target> <input>)" >&2
    exit 1
fi
echo "fuzz: ${#TARGETS[@]} targets, ${SECONDS_PER_TARGET}s each, no crash" >&2
