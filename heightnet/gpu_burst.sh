#!/usr/bin/env bash
# HeightNet v2 on a GPU machine lent for a few minutes (one NVIDIA GPU, many cores, nothing kept):
# render fresh training cameras on every core, cache them, resume the committed state there with
# the whole network learning (detection head and trunk together), and stop in time with the state
# written to OUT_DIR, whence it is copied back and committed like any other stop.
#   [BURST_SIZES=WxH,...] bash heightnet/gpu_burst.sh OUT_DIR SECONDS [RENDER_SECONDS [DEVICE [TRAIN ARGS...]]]
# TRAIN ARGS go to `heightpipe train` after the script's own (e.g. --set train_v2.head_only=true);
# BURST_SIZES replaces the rendered sizes (default 640x480,640x360,320x240); PYTHON the
# interpreter (default python3, the GPU machine's).
# Rendering grows the set BURST_CHUNK (default 400) sequences at a time (finished sequences are
# kept; the first chunk always) until RENDER_SECONDS (default 160) have passed; the rest of SECONDS trains.
# The batch is 8x the 2-core machine's (32 pairs); the learning rate is doubled (lr 0.002 before
# the config's drops: 1.8e-4 for the network, 10x that for the head), about the square root of 8.
set -euo pipefail
out=${1:?usage: gpu_burst.sh OUT_DIR SECONDS [RENDER_SECONDS [DEVICE [TRAIN ARGS...]]]}
budget=${2:?seconds this call may take}
render_seconds=${3:-160}
device=${4:-cuda}
shift $(( $# < 4 ? $# : 4 ))
sizes=${BURST_SIZES:-640x480,640x360,320x240}
chunk=${BURST_CHUNK:-400}
start=$SECONDS
cores=$(nproc)
hp() { "${PYTHON:-python3}" -m pipeline.cli "$@"; }
say() { echo "[$(( SECONDS - start )) s] $*"; }

mkdir -p "$out"
cp heightnet/state/v2/checkpoint.pt heightnet/state/v2/log.csv heightnet/state/v2/curve.csv "$out"/
# 320x240 beside 640x480 and 640x360: the held-out 320x240 renders are what the head misread
# (whether they cost the first burst its real-clip coverage is open: docs/results.md, 2026-12-04).
# The first chunk is always rendered: without it there is nothing to train on (bash counts SECONDS
# in whole seconds, so a 1 s render budget could be spent before the loop began).
for (( sequences = chunk; sequences <= 8 * chunk; sequences += chunk )); do
    (( sequences == chunk || SECONDS - start < render_seconds )) || break
    say "rendering up to $sequences training cameras on $cores cores"
    hp synth --out data/burst_train --sequences "$sequences" --frames 2 --size "$sizes" \
        --seed 21 --split train --workers "$cores" --no-progress
done
left=$(( budget - (SECONDS - start) - 60 ))   # cache, loader start-up and the last write
if (( left < 60 )); then say "no time left to train"; exit 1; fi
say "training for $left s on $device"
hp train --resume --out "$out" --no-progress --max-minutes "$(( left / 60 )).$(( left % 60 * 10 / 60 ))" \
    --set train_v2.data=data/burst_train --set 'train_v2.test_data=""' --set "train_v2.device=\"$device\"" \
    --set "train_v2.loader_workers=$(( cores > 2 ? cores - 2 : 1 ))" --set train_v2.batch_size=32 \
    --set train_v2.lr=0.002 --set train_v2.head_only=false --set train_v2.checkpoint_every=250 \
    --set train_v2.log_every=25 "$@"
say "done"
