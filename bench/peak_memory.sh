#!/bin/bash
# usage: bash bench/peak_memory.sh LOG CMD...
# Runs CMD and samples the summed resident memory (VmRSS) of CMD, its
# children and grandchildren every 0.1 s; writes the exit status, the wall
# time, the peak, when it came and each process's share to LOG (and CMD's
# output to LOG.out). Linux only (/proc). docs/BENCHMARKS.md, "The
# lattice's stored state".
set -u
log=$1
shift
"$@" > "$log.out" 2>&1 &
root=$!
peak=0 peak_ms=0 peak_detail=""
start=$(date +%s%N)
while kill -0 "$root" 2>/dev/null; do
  pids="$root"
  for child in $(pgrep -P "$root"); do pids="$pids $child $(pgrep -P "$child" | tr '\n' ' ')"; done
  sum=0 detail=""
  for p in $pids; do
    r=$(awk '/VmRSS/ {print $2}' "/proc/$p/status" 2>/dev/null)
    [ -n "$r" ] || continue
    sum=$((sum + r))
    detail="$detail $(cat "/proc/$p/comm" 2>/dev/null):$((r / 1024))M"
  done
  if [ "$sum" -gt "$peak" ]; then
    peak=$sum peak_ms=$((($(date +%s%N) - start) / 1000000)) peak_detail=$detail
  fi
  sleep 0.1
done
wait "$root"
rc=$?
wall_ms=$((($(date +%s%N) - start) / 1000000))
echo "rc=$rc wall ${wall_ms} ms; peak summed RSS $((peak / 1024)) MB at ${peak_ms} ms:$peak_detail" | tee "$log"
exit $rc
