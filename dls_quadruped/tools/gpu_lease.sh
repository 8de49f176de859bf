#!/usr/bin/env bash
# One short GPU lease, run from the checkout's root on a node with torch + CUDA but no network (docs/gpu.md
# "A short GPU lease"): unpack the [gpu] wheels packed by `make gpu-pack` (and the caches of `make gpu-caches`, if
# carried), then, each within its own time box and writing into $OUT:
#   mpc      the sampling MPC's warp kernel over M and B (bench/mpc_warp.py)                      MPC_S (default 150 s)
#   scaling  solve time against M x B, the cost-against-work grid (bench/mpc_scaling.py)          SCALING_S (150 s)
#   check    `make gpu-check`'s env sections: graph, syncs, launches, faults, env, gpu_busy, rough  CHECK_S (0: skipped)
#   loop     the closed loop on the device, naive-warm-start MPC, LOOP_B robots (bench/device.py)  LOOP_S (150 s)
#   train    base at TRAIN_ENVS (4 096) robots, continued from TRAIN_FROM                         TRAIN_S (what is left)
#            (TRAIN_ARGS: more train arguments, e.g. "--set scene.cuda_graph=true": the step as one CUDA graph)
# and pack the compile caches it filled for the next node (carried caches, e.g. `make gpu-aot` + `make gpu-caches`,
# are unpacked first; cache_sizes.txt lists the Warp modules the node still compiled). LEASE_S (default 600) is the
# whole command's budget; SECTIONS (default "mpc train") chooses and orders the sections. Every section's output
# lands in $OUT even when a later one fails. LEASE_DEVICE=cpu runs the same sections on Warp's CPU device (backend
# warp-cpu): a dry run of the lease's commands on a machine without a GPU (tests/tools/test_gpu_pack.py).
set -u
T0=$(date +%s)
OUT=${OUT:?set OUT to the folder the results go to}
LEASE_S=${LEASE_S:-600}
SECTIONS=${SECTIONS:-"mpc train"}
PACK=${PACK:-.gpu_pack}
TRAIN_FROM=${TRAIN_FROM:-docs/policies/gpu/base_h200_resume.pt}
export PYTHONUNBUFFERED=1 SITE=${SITE:-/tmp/gpu_site} CACHES=${CACHES:-/tmp/gpu_caches}
export WARP_CACHE_PATH=$CACHES/warp TORCHINDUCTOR_CACHE_DIR=$CACHES/inductor
left() { echo $(( LEASE_S - ($(date +%s) - T0) )); }
DEVICE=${LEASE_DEVICE:-cuda}
case $DEVICE in
    cuda) BACKEND=cuda ;;
    cpu) BACKEND=warp-cpu ;;
    *) echo "gpu_lease: LEASE_DEVICE=$DEVICE (allowed: cuda, cpu)"; exit 2 ;;
esac

if [ ! -d "$SITE/warp" ]; then
    # the first call of a lease may have moved part 1 to /root (a call carries at most 64 MiB): look in both
    parts=$(for f in "$PACK"/gpu_site.tar.xz.part* /root/gpu_site.tar.xz.part*; do
                [ -f "$f" ] && echo "${f##*part} $f"
            done | sort -n -u -k1,1 | cut -d' ' -f2)
    mkdir -p "$SITE" && cat $parts | xz -d -T0 | tar -x -C "$SITE" \
        || { echo "gpu_lease: cannot unpack $parts"; exit 2; }
fi
caches=$(ls "$PACK"/gpu_caches.tar.xz.part* 2>/dev/null)
[ -n "$caches" ] && mkdir -p "$CACHES" && cat $caches | xz -d -T0 | tar -x -C "$CACHES"
export PYTHONPATH=$PWD:$SITE:${PYTHONPATH:-}
echo "unpacked after $(( $(date +%s) - T0 )) s"
touch /tmp/lease_t0_$$  # Warp kernels newer than this were compiled on the node, not loaded from the carried cache
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$OUT/machine.txt"
python -c "import sys, torch, warp; print(sys.version.split()[0], torch.__version__, warp.__version__)" 2>&1 \
    | tail -1 | tee -a "$OUT/machine.txt"
git rev-parse HEAD 2>/dev/null >> "$OUT/machine.txt"

for section in $SECTIONS; do
    case $section in
    mpc)
        budget=$(( ${MPC_S:-150} < $(left) - 60 ? ${MPC_S:-150} : $(left) - 60 ))
        timeout $(( budget + 30 )) python -m dls_quadruped.bench.mpc_warp --device "$DEVICE" --budget-s "$budget" \
            --out "$OUT/mpc_warp.json" ${MPC_ARGS:-} 2>&1 | tail -40
        echo "mpc: rc ${PIPESTATUS[0]} after $(( $(date +%s) - T0 )) s" ;;
    scaling)
        budget=$(( ${SCALING_S:-150} < $(left) - 60 ? ${SCALING_S:-150} : $(left) - 60 ))
        timeout $(( budget + 30 )) python -m dls_quadruped.bench.mpc_scaling --device "$DEVICE" --budget-s "$budget" \
            --out "$OUT" ${SCALING_ARGS:-} 2>&1 | tail -30
        echo "scaling: rc ${PIPESTATUS[0]} after $(( $(date +%s) - T0 )) s" ;;
    check)
        budget=${CHECK_S:-0}
        [ "$budget" -gt 0 ] && timeout $(( budget + 60 )) python -m dls_quadruped.bench.gpu_check --out "$OUT/check" \
            --device "$DEVICE" --budget-s "$budget" --skip compile,trajectories,mpc,train ${CHECK_ARGS:-} \
            > "$OUT/gpu_check.log" 2>&1
        cp "$OUT/check/report.json" "$OUT/gpu_check.json" 2>/dev/null; rm -rf "$OUT/check"
        echo "check: after $(( $(date +%s) - T0 )) s" ;;
    loop)
        budget=$(( ${LOOP_S:-150} < $(left) - 60 ? ${LOOP_S:-150} : $(left) - 60 ))
        timeout "$budget" python -m dls_quadruped.bench.device --device "$DEVICE" --backend "$BACKEND" --tasks --samples \
            --closed-loop-robots "${LOOP_B:-1024}" --out "$OUT/loop" ${LOOP_ARGS:-} 2>&1 | tail -12
        echo "loop: rc ${PIPESTATUS[0]} after $(( $(date +%s) - T0 )) s"
        cp "$OUT/loop/device.json" "$OUT/closed_loop_$DEVICE.json" 2>/dev/null; rm -rf "$OUT/loop" ;;
    train)
        budget=${TRAIN_S:-$(( $(left) - 45 ))}
        run=/tmp/lease_run_$$
        timeout $(( budget + 60 )) python -m dls_quadruped.learning.train --task base --device "$DEVICE" --backend "$BACKEND" \
            --num-envs "${TRAIN_ENVS:-4096}" --iterations 100000 --resume-from "$TRAIN_FROM" --time-limit "$budget" --run-dir "$run" \
            --save-every-min 3 ${TRAIN_ARGS:-} > "$OUT/train.log" 2>&1
        echo "train: rc $? after $(( $(date +%s) - T0 )) s"
        grep -E "time limit|Traceback|Error" "$OUT/train.log" | head -5
        python - "$run" "$OUT" <<'PY'
import glob, sys, torch
run, out = sys.argv[1:]
cks = sorted(glob.glob(f"{run}/model_*.pt"), key=lambda p: int(p.rsplit("_", 1)[1][:-3]))
ck = torch.load(cks[-1], weights_only=False, map_location="cpu")
ck["env_state"].pop("episodes", None)  # 4 096 robots' episodes in progress (~20 MB): a resume restarts them
torch.save(ck, f"{out}/base_gpu_resume.pt")
print("checkpoint", cks[-1], "iteration", ck["iter"])
PY
        python -m dls_quadruped.viz.learning_curve "$run" --csv "$OUT/learning_curve.csv" \
            --png "$OUT/learning_curve.png" 2>&1 | tail -1
        cp "$run/exported/policy.pt2" "$OUT/base_gpu_actor.pt2" 2>/dev/null ;;
    *) echo "gpu_lease: unknown section $section (allowed: mpc scaling check loop train)"; exit 2 ;;
    esac
done
du -sb "$CACHES"/* 2>/dev/null | tee "$OUT/cache_sizes.txt"
echo "warp modules compiled on the node: $(find "$CACHES/warp" -name '*.sm*' -newer /tmp/lease_t0_$$ | wc -l)," \
    "carried: $(find "$CACHES/warp" -name '*.sm*' ! -newer /tmp/lease_t0_$$ | wc -l)" | tee -a "$OUT/cache_sizes.txt"
find "$CACHES/warp" -name '*.sm*' -newer /tmp/lease_t0_$$ -printf '%f\n' 2>/dev/null | sort >> "$OUT/cache_sizes.txt"
# at most 8 files of <= 16 MB come back (caches without Warp's sources and LTO, as gpu_pack.warp_cache_member;
# xz -T0 here, fast on the node's cores): the small results in one tar, the checkpoint, the caches in 15 MB parts
(cd "$OUT" && tar -cf results.tar --exclude=results.tar --exclude='*.pt' --exclude='gpu_caches*' . \
    && find . -maxdepth 1 -type f ! -name results.tar ! -name '*.pt' -delete)
(cd "$CACHES" && tar -cf - --exclude='./warp/*.cu' --exclude='./warp/*/lto' . | xz -1 -T0 > /tmp/gpu_caches.tar.xz) && [ "$(left)" -gt 5 ] && \
    split -b 15M -a 1 /tmp/gpu_caches.tar.xz "$OUT/gpu_caches.tar.xz.part"
ls -la "$OUT"
echo "gpu_lease: done after $(( $(date +%s) - T0 )) s"
