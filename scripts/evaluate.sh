#!/usr/bin/env bash
# The README's accuracy section (`make evaluate`, after setup), on a quiet machine:
#  1. the paper's protocols through the whole graph (20 static points x 10 trials,
#     20-120 km/h x 10 runs) and latency as on the train (sensor bags replayed at real
#     time): the run that must finish in under 30 minutes (it prints its wall time);
#  2. the ablations, every positioning method side by side, lamp outage and forged lamp;
#  3. one report over all of it, written into README.md and the companion docs;
#  4. the paper's protocols on the realistic rig profile, with the same statistics (10
#     trials per static point, 10 runs per speed, a drawn installation per seed), the
#     README's headline table, beside 3. and the paper;
#  5. the error budget of the realistic profile (each error source alone), its table
#     written into README.md;
#  6. the fault protocol (one fault per run, alone on the machine), its table written
#     into README.md and docs/arch/evaluation.md.
# Bags, logs and report: out/eval/ (OUT=... to change).
set -eo pipefail
cd "$VLC_WS"
out="${OUT:-out/eval}"
rm -f /dev/shm/fastrtps_* /dev/shm/sem.fastrtps_* 2>/dev/null || true
# The run log lists the commands that recorded the bags: this evaluation re-records them;
# the latency log lists the latency replays from this evaluation on (re-runs append).
rm -f "$out/runs.jsonl" "$out/latency_runs.jsonl"
# Every step's camera nodes share one memo of their start-up arrays (lens maps, noise
# banks: the same few installations and seeds recur); emptied here, so it holds only
# this evaluation's entries (a few GB at most).
export VLC_RIG_CACHE_DIR="$(realpath -m "$out")/rig_cache"
rm -rf "$VLC_RIG_CACHE_DIR"
ros2run vlc_evaluation run_evaluation --protocol full --latency --out "$out"
ros2run vlc_evaluation run_evaluation --protocol companions --ablations \
    --ablation-trials 1 --ablation-runs 1 --out "$out"
ros2run vlc_evaluation run_evaluation --protocol full --latency --ablations \
    --ablation-trials 1 --ablation-runs 1 --companions --outage --forged --rescore \
    --out "$out" --readme README.md \
    --companions-docs docs/arch/evaluation.md docs/arch/companion_localizers.md
ros2run vlc_evaluation run_evaluation --protocol full --rig-profile realistic \
    --out "$out/realistic" --profile-docs README.md
ros2run vlc_evaluation run_evaluation --protocol none --budget --out "$out/budget" \
    --budget-docs README.md
ros2run vlc_evaluation run_evaluation --protocol none --faults --out "$out/faults" \
    --faults-docs README.md docs/arch/evaluation.md
