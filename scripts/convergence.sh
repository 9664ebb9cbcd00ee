#!/usr/bin/env bash
# Convergence study for docs/validation.md: relative error of the elastica tip deflection
# (lambda = 1) and of the first cantilever frequency against the number of segments, and of the
# elastica against the time step. Usage: scripts/convergence.sh [path/to/vcsim]
set -euo pipefail
VCSIM=${1:-build/bin/vcsim}
err() { /usr/bin/python3 -c 'import json,sys; d=json.load(sys.stdin); print("%.3e" % d[0]["rel_error"])'; }
echo "| segments | elastica y_tip/L error (lambda=1) | f1 error |"
echo "|---|---|---|"
for n in 8 16 32 64 128; do
  e=$("$VCSIM" validate elastica-tip --load 1 --segments "$n" --json | err)
  f=$("$VCSIM" validate frequency --mode 1 --segments "$n" --json | err)
  echo "| $n | $e | $f |"
done
echo
echo "| dt (s) | elastica y_tip/L error (40 segments) |"
echo "|---|---|"
for dt in 2e-6 1e-6 5e-7 2.5e-7; do
  e=$("$VCSIM" validate elastica-tip --load 1 --segments 40 --dt "$dt" --json | err)
  echo "| $dt | $e |"
done
