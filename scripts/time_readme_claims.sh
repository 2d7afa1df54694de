#!/usr/bin/env bash
# Time what README.md quotes in seconds or minutes, and write the figures with the machine's state to
# benchmarks/results/readme_timings.json (one entry per part, replaced on each run).
#
#   bash scripts/time_readme_claims.sh                  # all parts: demo, quick, full (~20 min on 2 idle cores)
#   bash scripts/time_readme_claims.sh demo quick       # some of them
#
#   demo    `cylindersplat demo` into a temporary folder (the README's main job, shipped weights)
#   quick   `python -m pytest -q -m "not slow"` (the README's quick local run)
#   full    `python -m pytest -q` (everything, as scripts/test.sh and CI run it; installs nothing)
#
# The figures are only worth quoting from an idle machine: each entry records the load average (1 min) before
# and after, the CPU count and model, so a busy run is recognisable as one. Nothing is installed.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/_python.sh
choose_python

parts=("$@")
[ ${#parts[@]} -eq 0 ] && parts=(demo quick full)
out=benchmarks/results/readme_timings.json
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT

for part in "${parts[@]}"; do
    case "$part" in
        demo) command=("$PYTHON" -m cylindersplat demo --out "$scratch/demo"); shown="cylindersplat demo" ;;
        quick) command=("$PYTHON" -m pytest -q -p no:cacheprovider -m "not slow"); shown='python -m pytest -m "not slow"' ;;
        full) command=("$PYTHON" -m pytest -q -p no:cacheprovider); shown="python -m pytest" ;;
        *) echo "time_readme_claims.sh: unknown part '$part' (demo, quick, full)" >&2; exit 2 ;;
    esac
    load_before=$(cut -d' ' -f1 /proc/loadavg)
    start=$(date +%s.%N)
    status=0
    "${command[@]}" >"$scratch/$part.log" 2>&1 || status=$?
    end=$(date +%s.%N)
    load_after=$(cut -d' ' -f1 /proc/loadavg)
    summary=$(grep -v '^\s*$' "$scratch/$part.log" | tail -n 1)
    "$PYTHON" - "$out" "$part" "$start" "$end" "$load_before" "$load_after" "$status" "$summary" "$shown" <<'EOF'
import json, os, platform, subprocess, sys, time
from pathlib import Path

out, part, start, end, before, after, status, summary, command = sys.argv[1:]
path = Path(out)
results = json.loads(path.read_text()) if path.is_file() else {}
cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
            if line.startswith("model name")), platform.processor())
commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
results[part] = {
    "command": command,
    "seconds": round(float(end) - float(start), 1),
    "exit_status": int(status),
    "last_line": summary,
    "load_1min_before": float(before),
    "load_1min_after": float(after),
    "cpus": os.cpu_count(),
    "cpu": cpu,
    "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(float(end))),
    "commit": commit,
}
path.parent.mkdir(parents=True, exist_ok=True)
path.write_text(json.dumps(results, indent=1) + "\n")
print(f"{part}: {results[part]['seconds']} s (exit {status}; load {before} -> {after} on {os.cpu_count()} CPUs) -> {out}")
EOF
done
