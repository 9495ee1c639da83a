#!/usr/bin/env bash
# RUSTC_WRAPPER used by `FUZZ_SCOPE=own fuzz/run.sh`: adds the SanitizerCoverage flags only to
# the crates of the workspace being fuzzed (their CARGO_MANIFEST_DIR lies under
# $FUZZ_OWN_ROOT), so libFuzzer's cov:/ft: count taxel's own edges and comparisons, not those
# of toml, serde, bincode or flate2 (which are still linked and run, just not instrumented).
# Build scripts and proc macros are never instrumented (they run on the host, without libFuzzer).
rustc="$1"
shift
own=0
case "${CARGO_MANIFEST_DIR:-}" in
"$FUZZ_OWN_ROOT" | "$FUZZ_OWN_ROOT"/*) own=1 ;;
esac
for a in "$@"; do
    case "$a" in
    build_script_build | build_script_main | proc-macro | ___) own=0 ;;
    esac
done
if [ "$own" = 1 ]; then
    # shellcheck disable=SC2086 # the flags are separate words on purpose
    exec "$rustc" "$@" $FUZZ_SANCOV_FLAGS
fi
exec "$rustc" "$@"
