#!/bin/bash
# pbdyn on a SLURM array: one task per shard of the experiment, each into its own store, then one merge.
#
#   sbatch --array=1-64 tools/templates/slurm_array.sh scenarios/datasets/controlled_2d.toml results
#   # when every task has finished (or chained: sbatch --dependency=afterok:<array job id> ...):
#   pbdyn merge results/shard-*.sqlite --out results/controlled_2d.sqlite
#
# Each task flies the SLURM_ARRAY_TASK_ID-th of SLURM_ARRAY_TASK_COUNT contiguous blocks of the experiment's maps
# (pbdyn batch --shard I/N) with the CPUs it was given, writes its store on the node's local disk (SQLite locking is
# unreliable on network file systems) and copies it next to the others only when the shard is complete. Resubmitting
# the array re-flies only unfinished shards (a complete shard's store is copied in and has nothing left to run).
#SBATCH --job-name=pbdyn
#SBATCH --cpus-per-task=4
#SBATCH --mem-per-cpu=2G
#SBATCH --time=02:00:00
#SBATCH --output=pbdyn-%A_%a.log
set -euo pipefail

SCENARIO=${1:?usage: sbatch --array=1-N slurm_array.sh SCENARIO OUTDIR}
OUTDIR=${2:?usage: sbatch --array=1-N slurm_array.sh SCENARIO OUTDIR}
PBDYN=${PBDYN:-pbdyn}                       # e.g. PBDYN=/path/to/pbdyn/.venv/bin/pbdyn
I=${SLURM_ARRAY_TASK_ID:?run this script with sbatch --array}
N=${SLURM_ARRAY_TASK_COUNT:?run this script with sbatch --array}

mkdir -p "$OUTDIR"
LOCAL=${SLURM_TMPDIR:-${TMPDIR:-/tmp}}/pbdyn-shard-$I.sqlite
if [ -f "$OUTDIR/shard-$I.sqlite" ] && [ ! -f "$LOCAL" ]; then
    cp "$OUTDIR/shard-$I.sqlite" "$LOCAL"     # a shard completed by an earlier submission
fi
"$PBDYN" batch "$SCENARIO" --out "$LOCAL" --shard "$I/$N" --workers "${SLURM_CPUS_PER_TASK:-1}"
cp "$LOCAL" "$OUTDIR/shard-$I.sqlite.part"
mv "$OUTDIR/shard-$I.sqlite.part" "$OUTDIR/shard-$I.sqlite"
