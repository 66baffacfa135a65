#!/usr/bin/env bash
# One lent-GPU session of skeleton training, end to end, in one command (the device tool
# allows one run of at most 10 minutes and returns only what is under $OUT).
#
#   training/skeleton/device_run.sh CARRY OUT MINUTES
#
# CARRY holds `rigserve.gz` (the release binary, gzipped) and `rigs_s.tgz` (the `train`
# rigs of ../shared/rigs reduced by `training/skeleton/strip_glb.py`, which keeps exactly
# what `rigserve dataset` reads). On the device: synthetic characters are generated, every
# data set is written by `rigserve dataset` (the crate's own loader and tokenizer, as on
# CPU), and three runs of `train_fast` share the GPU for MINUTES each:
#   A  from scratch, all `train` rigs + synthetic          (candidate to ship)
#   A2 from the shipped model (models/skeleton), same data  (candidate to ship)
#   B  from scratch, `train` without `hold` + synthetic    (judged on `hold`, which it never saw)
# Their weights (`OUT/{A,A2,B}/last.pt`, written every minute) and logs come back.
# RUNS="A B" trains only those; SYN_SETS, SYN_COUNT, REAL_AUG, SYN_AUG, BATCH and
# TRAIN_EXTRA (more train_fast flags) size the rest.
set -u
carry=$1 out=$2 minutes=$3
syn_sets=${SYN_SETS:-8} syn_count=${SYN_COUNT:-5000} real_aug=${REAL_AUG:-200} syn_aug=${SYN_AUG:-1}
batch=${BATCH:-256} extra=${TRAIN_EXTRA:-} runs=${RUNS:-A A2 B}
w=${WORK:-/tmp/rigwork}
t0=$(date +%s)
say() { echo "[device_run +$(( $(date +%s) - t0 ))s] $*"; }
mkdir -p "$w" "$out"
exec > >(tee -a "$out/run.log") 2>&1

say "host: $(nproc) cores; $(python3 -c 'import torch; print(torch.__version__, torch.cuda.is_available() and torch.cuda.get_device_name(0))')"
gunzip -c "$carry/rigserve.gz" > "$w/rigserve" && chmod +x "$w/rigserve" || exit 1
tar xzf "$carry/rigs_s.tgz" -C "$w" || exit 1
python3 -m training.skeleton.holdout --rigs "$w/rigs_s" --out "$w/rigs_hold" || exit 1

# Synthetic characters: seeds 101.. (training used 5, evaluation uses 77), two processes each.
# (`wait` is always given pids: a bare one would also wait for the `tee` above.)
pids=()
for k in $(seq 1 "$syn_sets"); do
  python3 -m training.synth.generate --out "$w/syn_$k" --count "$syn_count" --seed $((100 + k)) --workers 2 --quiet &
  pids+=($!)
done
wait "${pids[@]}"
mkdir -p "$w/syn" && echo -e "file\tsplit\tcategory" > "$w/syn/manifest.tsv"
for k in $(seq 1 "$syn_sets"); do
  [ -f "$w/syn_$k/manifest.tsv" ] || { say "synthetic set $k failed"; continue; }
  tail -n +2 "$w/syn_$k/manifest.tsv" >> "$w/syn/manifest.tsv"
  ln -s "$w/syn_$k"/*.glb "$w/syn/"
done
say "synthetic: $(( $(wc -l < "$w/syn/manifest.tsv") - 1 )) characters"

rs="$w/rigserve"
$rs dataset --input "$w/syn" --out "$w/ds_syn" --points 2048 --augment "$syn_aug" --seed 11 | tail -1
$rs dataset --input "$w/rigs_s" --split train --out "$w/ds_real" --points 2048 --augment "$real_aug" --seed 12 | tail -1
$rs dataset --input "$w/rigs_hold" --split train --out "$w/ds_real_h" --points 2048 \
  --augment $(( real_aug * 140 / 106 )) --seed 12 | tail -1
say "data sets written"

scratch="--latents 64 --d-model 192 --heads 6 --layers 4 --d-ff 768 --dropout 0.05 --lr 8e-4 --coord-sigma 2 --coord-sigma-end 1"
common="--mix 1,1 --minutes $minutes --batch $batch --threads 2 --ckpt-seconds 60 $extra"
pids=()
for run in $runs; do
  case $run in
    A) args=(--data "$w/ds_real" $scratch --seed 21) ;;
    A2) args=(--data "$w/ds_real" --init-onnx models/skeleton --lr 1.5e-4 --coord-sigma 1 --seed 22) ;;
    B) args=(--data "$w/ds_real_h" $scratch --seed 23) ;;
    *) say "unknown run $run"; continue ;;
  esac
  python3 -m training.skeleton.train_fast "${args[@]}" --data "$w/ds_syn" --out "$out/$run" $common &
  pids+=($!)
done
# Sampled while the runs train: whether the GPU or the Python side of each run limits it.
(sleep 120; nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv 2>/dev/null) &
wait "${pids[@]}"
say "done"
ls -la "$out" "$out"/*
