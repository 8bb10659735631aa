#!/usr/bin/env bash
# Builds the fuzz targets with libFuzzer's coverage instrumentation on the stable toolchain
# (plain rustc codegen options: no nightly, no cargo-fuzz) and runs each for SECONDS seconds
# (default 60), one after the other, at the lowest priority. Corpora grow in
# fuzz/corpus/TARGET (seeded from fuzz/seeds/TARGET); crashing inputs land in
# fuzz/artifacts/TARGET and make the script fail. See docs/fuzzing.md.
#
#   bash fuzz/run.sh [SECONDS] [TARGET...]
set -euo pipefail
cd "$(dirname "$0")"
seconds="${1:-60}"
shift || true
targets=("$@")
if [ "${#targets[@]}" -eq 0 ]; then
    targets=(obj scene_file environment photometric capi_sequence)
fi
host="$(rustc -vV | sed -n 's/^host: //p')"
# SanitizerCoverage as cargo-fuzz sets it up, minus its nightly-only sanitizer flags. The
# explicit --target keeps these flags off build scripts and proc macros.
export RUSTFLAGS="-Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares --cfg fuzzing -Cforce-frame-pointers=yes"
cargo build --release --locked --target "$host" --target-dir target --bins
failed=0
for t in "${targets[@]}"; do
    mkdir -p "corpus/$t" "artifacts/$t"
    echo "== fuzz $t for ${seconds}s"
    start=$(date +%s)
    # Inputs that once crashed or hung stay fixed: replay them first.
    known=(known/"$t"-*)
    if [ -e "${known[0]}" ]; then
        if ! "target/$host/release/$t" -timeout=10 -rss_limit_mb=4096 "${known[@]}" \
            2> "artifacts/$t.known.log"; then
            echo "fuzz $t: a known input fails again; log in fuzz/artifacts/$t.known.log" >&2
            tail -n 30 "artifacts/$t.known.log" >&2
            failed=1
        fi
    fi
    if ! nice -n 19 "target/$host/release/$t" "corpus/$t" "seeds/$t" \
        -max_total_time="$seconds" -timeout=10 -rss_limit_mb=4096 -max_len=65536 \
        -artifact_prefix="artifacts/$t/" -print_final_stats=1 2> "artifacts/$t.log"; then
        echo "fuzz $t: crash or hang; input in fuzz/artifacts/$t/, log in fuzz/artifacts/$t.log" >&2
        tail -n 30 "artifacts/$t.log" >&2
        failed=1
    fi
    grep -E "stat::number_of_executed_units|stat::peak_rss_mb" "artifacts/$t.log" || true
    echo "fuzz $t: $(( $(date +%s) - start ))s, corpus $(ls "corpus/$t" | wc -l) inputs"
done
exit "$failed"
