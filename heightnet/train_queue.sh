#!/usr/bin/env bash
# The shipped model's training, ablation and units comparison, one after another (2-core CPU:
# never in parallel). Every step resumes, so re-running after an interruption continues.
#   nohup nice -n 10 bash heightnet/train_queue.sh [PID_TO_WAIT_FOR] > runs/queue.log 2>&1 &
set -euo pipefail
if [[ -n "${1:-}" ]]; then
    while kill -0 "$1" 2>/dev/null; do sleep 30; done
fi
hp() { python -m pipeline.cli "$@"; }
run() {  # run folder, extra --set options...
    local out=$1; shift
    local resume=(); [[ -f "$out/checkpoint.pt" ]] && resume=(--resume)
    hp train --out "$out" --no-progress "${resume[@]}" "$@"
    hp export --checkpoint "$out/checkpoint.pt" --out "$out/model.onnx"
}
run runs/heightnet_light                                   # shipped: relative target, consistency on
run runs/heightnet_light_nocons --set train.consistency_weight=0   # ablation
hp eval data/synth_test --model runs/heightnet_light/model.onnx \
    --ablation runs/heightnet_light_nocons/model.onnx --out runs/eval --set output.progress=false
run runs/heightnet_light_metres --set train.target=metres  # units comparison
hp eval data/synth_test --model runs/heightnet_light_metres/model.onnx --label metres \
    --out runs/eval_metres --set output.progress=false
echo "queue done: compare runs/eval/table.md with runs/eval_metres/table.md, then copy the better"
echo "model.onnx to stages/models/heightnet.onnx"
