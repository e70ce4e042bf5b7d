#!/usr/bin/env bash
# Soak test: run the default scenario for a long time (default 30 min) under
# the supervisor, sampling every period (default 60 s) the resident memory of
# every stage and of the launcher, the shared-memory files of the run and the
# sensor->control latency percentiles of that period; then print the summary
# (RSS growth first->last sample, per-period p99 first/median/max/last, drift).
#
#   tools/soak/soak.sh [DURATION_S] [PERIOD_S] [OUTDIR] [-- extra `beliefbus run` args]
#
# Outputs OUTDIR/soak.jsonl (one line per period), OUTDIR/soak.json (report,
# summary under "timeline"), OUTDIR/soak.log. Uses target/release binaries
# (build them first: cargo build --release), copied to OUTDIR/bin so that a
# rebuild during the soak cannot swap them underneath it.
set -euo pipefail
here="$(cd "$(dirname "$0")/../.." && pwd)"
duration="${1:-1800}"
period="${2:-60}"
out="${3:-$here/target/soak}"
shift $(( $# > 3 ? 3 : $# )) || true
[ "${1:-}" = "--" ] && shift
mkdir -p "$out/bin"
for b in beliefbus beliefbus-ingest beliefbus-filter beliefbus-control beliefbus-refine beliefbus-plant; do
  cp "$here/target/release/$b" "$out/bin/$b"
done
cd "$here"
"$out/bin/beliefbus" run configs/default.toml --duration "$duration" --quiet \
  --timeline "$out/soak.jsonl" --timeline-period "$period" \
  --report "$out/soak.json" "$@" > "$out/soak.log" 2>&1
status=$?
echo "exit $status; timeline $out/soak.jsonl; report $out/soak.json"
jq '.timeline' "$out/soak.json"
jq -r '"restarts \(.supervisor.restarts)  files_left \(.shared_memory.files_left)"' "$out/soak.json"
exit $status
