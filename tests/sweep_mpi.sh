#!/usr/bin/env bash
# `mpirun -np K ukdyn sweep ...` writes the same results.csv as one process (docs/sweeps.md).
# Usage: sweep_mpi.sh UKDYN SOURCE_DIR MPIEXEC. A ctest entry with the label mpi.
set -euo pipefail
ukdyn=$1; src=$2; mpiexec=$3
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
# A container has no InfiniBand and often no usable shared-memory transport checks: keep it simple.
export OMPI_MCA_btl=self,tcp OMPI_MCA_btl_tcp_if_include=lo OMPI_MCA_oob_tcp_if_include=lo
export OMPI_MCA_rmaps_base_oversubscribe=1 OMPI_MCA_hwloc_base_binding_policy=none
dir=$(mktemp -d "${TMPDIR:-/tmp}/ukdyn_sweep_mpi.XXXXXX")
trap 'rm -rf "$dir"' EXIT
cat > "$dir/s.yaml" <<YAML
ukdyn_sweep: 1
name: mpi_test
base: $src/scenarios/paper_free.yaml
mode: random
seed: 12345
samples: 200
parameters:
  - name: platform_mass
    path: ["subsystems[left].params.platform_mass", "subsystems[right].params.platform_mass"]
    distribution: {type: truncated_normal, mean: 50, sd: 5, low: 45, high: 60}
  - name: link2_mass
    path: subsystems[left].params.link_mass[1]
    distribution: {type: uniform, low: 3, high: 5}
set:
  simulation.t_end: 0.05
  simulation.abs_tol: 1e-10
  simulation.rel_tol: 1e-10
metrics: [max_residual, energy_drift, max_abs_Qc, final_state]
YAML
"$ukdyn" sweep "$dir/s.yaml" --no-figures -q --threads 1 -o "$dir/one"
[ "$(wc -l < "$dir/one/results.csv")" -eq 201 ] || { echo "FAIL: expected 200 rows"; exit 1; }
for np in 1 2 4; do
  "$mpiexec" --oversubscribe -np "$np" "$ukdyn" sweep "$dir/s.yaml" --no-figures -q --threads 1 \
    -o "$dir/np$np"
  if ! cmp "$dir/one/results.csv" "$dir/np$np/results.csv"; then
    echo "FAIL: mpirun -np $np wrote another table"; diff "$dir/one/results.csv" "$dir/np$np/results.csv" | head; exit 1
  fi
  cmp "$dir/one/summary.json" "$dir/np$np/summary.json" || { echo "FAIL: summary differs at -np $np"; exit 1; }
  echo "mpirun -np $np: the same results.csv and summary.json as one process"
done
