#!/usr/bin/env bash
# Coverage-guided fuzzing of taxel's parsers and loaders on stable Rust (no nightly, no
# cargo-fuzz): builds the libFuzzer targets with SanitizerCoverage instrumentation (the flags
# cargo-fuzz passes, minus the address sanitizer, which needs nightly), runs each target for a
# bounded time starting from the repository corpus, logs libFuzzer's coverage lines with the
# elapsed time, then merges what grew coverage back into fuzz/corpus/<target> (-merge=1 on
# edges only keeps just the inputs that reach new code, so the corpus stays small).
#
#   fuzz/run.sh [SECONDS_PER_TARGET] [TARGET...]     (default: 300 s, every target)
#
# Environment: FUZZ_TARGET_DIR (build dir, default /work/targets/fuzz if /work/targets exists,
# else target/fuzz), FUZZ_OUT (logs, work corpora, crash artifacts; default
# $FUZZ_TARGET_DIR/runs), FUZZ_NICE (niceness, default 15), FUZZ_MERGE=0 to skip the merge.
# FUZZ_SRC builds from another checkout of the workspace (e.g. a `git archive HEAD` export while
# others edit the working tree); the corpus merged into is always this script's fuzz/corpus.
# FUZZ_SCOPE=own instruments only this workspace's crates (fuzz/instrument-own.sh), so the
# coverage counts and the plateau are about taxel's code and not about the TOML grammar or
# serde; its build goes to a separate directory (default ${FUZZ_TARGET_DIR}-own). A target with
# a dictionary in fuzz/dict/<target>.dict gets it (-dict=).
# One fuzzer at a time: the machine is shared. Exit code 1 if any target found a crash
# (the crashing input is in $FUZZ_OUT/artifacts/<target>/).
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
root="$(dirname "$here")"
secs="${1:-300}"
shift || true
all=(serial_binary serial_ascii recording_csv record_file mcap calibration curvature_model)
targets=("$@")
[ ${#targets[@]} -eq 0 ] && targets=("${all[@]}")

scope="${FUZZ_SCOPE:-all}"
case "$scope" in
all | own) ;;
*)
    echo "fuzz/run.sh: FUZZ_SCOPE=$scope: expected all or own" >&2
    exit 2
    ;;
esac
if [ -z "${FUZZ_TARGET_DIR:-}" ]; then
    if [ -d /work/targets ]; then FUZZ_TARGET_DIR=/work/targets/fuzz; else FUZZ_TARGET_DIR="$root/target/fuzz"; fi
    [ "$scope" = own ] && FUZZ_TARGET_DIR="$FUZZ_TARGET_DIR-own"
fi
out="${FUZZ_OUT:-$FUZZ_TARGET_DIR/runs}"
nice_level="${FUZZ_NICE:-15}"
triple="$(rustc -vV | sed -n 's/^host: //p')"

# --target keeps the instrumentation off build scripts and proc macros, as cargo-fuzz does.
sancov="-Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares"
checks="--cfg fuzzing -Cdebug-assertions -Coverflow-checks"
src="$(cd "${FUZZ_SRC:-$root}" && pwd)"
if [ "$scope" = own ]; then
    export RUSTFLAGS="$checks"
    export RUSTC_WRAPPER="$here/instrument-own.sh" FUZZ_OWN_ROOT="$src" FUZZ_SANCOV_FLAGS="$sancov"
else
    export RUSTFLAGS="$sancov $checks"
fi
echo "building instrumented targets ($scope crates) into $FUZZ_TARGET_DIR ..."
(cd "$src" && CARGO_TARGET_DIR="$FUZZ_TARGET_DIR" nice -n "$nice_level" \
    cargo build --release -p taxel-fuzz --bins --target "$triple")
bin="$FUZZ_TARGET_DIR/$triple/release"

mkdir -p "$out"
summary="$out/summary.txt"
: >"$summary"
crashed=0
for t in "${targets[@]}"; do
    work="$out/corpus/$t"
    art="$out/artifacts/$t/"
    log="$out/$t.log"
    rm -rf "$work"
    mkdir -p "$work" "$art"
    cp "$here/corpus/$t"/* "$work"/ 2>/dev/null || true
    echo "fuzzing $t for $secs s (log $log)"
    start=$SECONDS
    # Each libFuzzer line is prefixed with the seconds elapsed since the target started.
    set +e
    dict=()
    [ -f "$here/dict/$t.dict" ] && dict=(-dict="$here/dict/$t.dict")
    nice -n "$nice_level" "$bin/$t" "$work" "${dict[@]}" -max_total_time="$secs" -print_final_stats=1 \
        -artifact_prefix="$art" -timeout=10 -rss_limit_mb=2048 -max_len=8192 2>&1 |
        while IFS= read -r line; do printf '%5d %s\n' $((SECONDS - start)) "$line"; done >"$log"
    rc=${PIPESTATUS[0]}
    set -e
    # Plateau: the elapsed time of the last line that grew coverage (cov:) or features (ft:);
    # a REDUCE line can grow them too (the shorter input reaches an edge the longer one did not).
    last=$(grep -E ' #[0-9]+[[:space:]]+(NEW|REDUCE|INITED|pulse|DONE)' "$log" | tail -n 1 || true)
    last_cov=$( (grep -E ' #[0-9]+[[:space:]]+(NEW|REDUCE|INITED)' "$log" || true) | awk '
        { for (i = 1; i <= NF; i++) if ($i == "cov:") c = $(i + 1) }
        c != prev { t = $1; prev = c } END { print t }')
    last_ft=$( (grep -E ' #[0-9]+[[:space:]]+(NEW|REDUCE|INITED)' "$log" || true) | awk '
        { for (i = 1; i <= NF; i++) if ($i == "ft:") f = $(i + 1) }
        f != prev { t = $1; prev = f } END { print t }')
    execs=$(sed -n 's/.*stat::number_of_executed_units: *//p' "$log" | tail -n 1)
    line="$t ($scope): exit $rc, ${secs}s, execs ${execs:-?}, last: ${last#* }, cov last grew at ${last_cov:-?}s, ft last grew at ${last_ft:-?}s"
    echo "$line" | tee -a "$summary"
    if [ "$rc" -ne 0 ]; then
        crashed=1
        echo "  $t: CRASH, inputs in $art:" | tee -a "$summary"
        ls "$art" | sed 's/^/    /' | tee -a "$summary"
    fi
    if [ "${FUZZ_MERGE:-1}" != 0 ]; then
        before=$(ls "$here/corpus/$t" | wc -l)
        # Edges only (no hit counters, no comparison features): keeps the repository corpus
        # to the inputs that reach code nothing else in it reaches.
        nice -n "$nice_level" "$bin/$t" -merge=1 -use_counters=0 -use_cmp=0 \
            "$here/corpus/$t" "$work" >"$out/$t.merge.log" 2>&1 || true
        after=$(ls "$here/corpus/$t" | wc -l)
        echo "  corpus fuzz/corpus/$t: $before -> $after files" | tee -a "$summary"
    fi
done
echo "summary in $summary"
exit $crashed
