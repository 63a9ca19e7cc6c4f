#!/usr/bin/env bash
# A newcomer's path through the README, walked as written (CI itself starts from a fresh
# clone): `just run` on the default scene, their own TUM folder, real time, a process killed
# mid-run, the report read. Each step checks what the README promises; any failure stops it.
# Usage: tools/newcomer-path.sh [TUM_FOLDER]   (default: the shared sequence)
set -euo pipefail
cd "$(dirname "$0")/.."
tum=${1:-../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300}
work=$(mktemp -d /tmp/dynslam-newcomer.XXXXXX)
default_run=""
trap 'pkill -f "run-id nc-$$" 2>/dev/null || true; rm -rf "$work" $default_run' EXIT
dynslam=./target/release/dynslam
step() { printf '\n== newcomer path: %s\n' "$*"; }
fail() { echo "newcomer path: $*" >&2; exit 1; }
# The value of `key` in a run folder's status.json.
status_of() { python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))[sys.argv[2]])' "$1/status.json" "$2"; }
# Frames in frames.csv, and distinct frame numbers among them.
rows() { tail -n +2 "$1/frames.csv" | wc -l; }
distinct() { tail -n +2 "$1/frames.csv" | cut -d, -f1 | sort -u | wc -l; }

step "just run (the embedded default scene)"
out=$(just run 2>"$work/default.log") || { tail -20 "$work/default.log"; fail "just run failed"; }
run=$(echo "$out" | tail -n 1)
case "$run" in runs/*|*/runs/*) default_run=$run ;; esac   # ours: removed at exit
[ -f "$run/report.md" ] || fail "just run did not print a run folder with report.md last (got '$run')"
[ "$(status_of "$run" state)" = completed ] || fail "default run: $(status_of "$run" state)"
[ "$(rows "$run")" = 150 ] || fail "default run: $(rows "$run") frames recorded, the README says 150"

step "your own TUM folder (a copy of the sequence under the user's own name)"
mine="$work/rgbd_dataset_freiburg1_mine"
mkdir -p "$mine"
for f in rgb.txt depth.txt groundtruth.txt; do cp "$tum/$f" "$mine/"; done
ln -s "$(realpath "$tum/rgb")" "$mine/rgb"
ln -s "$(realpath "$tum/depth")" "$mine/depth"
out=$($dynslam run "$mine" --limit 60 --output-dir "$work/runs" --run-id "nc-$$-mine" 2>"$work/mine.log") \
    || { tail -20 "$work/mine.log"; fail "a run on a TUM folder failed"; }
run=$(echo "$out" | tail -n 1)
grep -q "tum-fr1" "$run/report.md" || fail "the folder name did not pick the tum-fr1 camera (report.md)"
[ -f "$run/eval.json" ] || fail "no eval.json for a folder with groundtruth.txt"

step "real time, the segmenter and the SLAM killed mid-run (README \"Testing fault isolation\")"
id="nc-$$-rt"
$dynslam run "$mine" --mode realtime --limit 150 --output-dir "$work/runs" --run-id "$id" \
    >"$work/rt.out" 2>"$work/rt.log" &
pid=$!
run="$work/runs/$id"
for _ in $(seq 300); do
    [ -f "$run/frames.csv" ] && [ "$(rows "$run")" -ge 30 ] && break
    sleep 0.1
done
[ -f "$run/frames.csv" ] && [ "$(rows "$run")" -ge 30 ] || fail "the real-time run recorded no 30 frames in 30 s"
pkill -9 -f "segmenter --run-id $id" || fail "no segmenter process to kill"
sleep 1
pkill -9 -f "slam --run-id $id" || fail "no slam process to kill"
wait "$pid" || { tail -20 "$work/rt.log"; fail "the killed run did not complete"; }
[ "$(status_of "$run" state)" = completed ] || fail "killed run: $(status_of "$run" state)"
[ "$(rows "$run")" = 150 ] && [ "$(distinct "$run")" = 150 ] \
    || fail "killed run: $(rows "$run") rows for $(distinct "$run") distinct frames (150 each expected)"
[ "$(status_of "$run" restarts)" -ge 2 ] || fail "killed run: status.json counts $(status_of "$run" restarts) restarts"

step "read the report (written again by dynslam report)"
rm "$run/report.md"
report=$($dynslam report "$run")
[ -f "$report" ] || fail "dynslam report printed '$report'"
grep -qi "restart" "$report" || fail "report.md does not mention the restarts"
grep -q "ATE" "$report" || fail "report.md has no ATE"
echo "newcomer path: every step as the README says"
