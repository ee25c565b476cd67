#!/usr/bin/env bash
# GMWM fit benchmark: dynacal vs a Python peer (numpy prefix-sum WV + scipy least_squares)
# on the same generated Table I series (WN + 2 GM, 100 Hz, seeded) at 1e6 and 1e7 samples,
# in one run. R (the reference gmwm/simts) is not installable here (no CRAN access).
# Needs python3 with numpy and scipy (pip install numpy scipy). Prints one line per tool.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -p dynacal --example fit_bench
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
for n in 1000000 10000000; do
  ./target/release/examples/fit_bench "$n" "$tmp/x.f64"
  python3 bench/fit_bench.py "$tmp/x.f64"
done
