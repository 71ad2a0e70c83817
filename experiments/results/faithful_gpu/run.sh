#!/usr/bin/env bash
# The shipped models on the faithful physics, one host of 2 GPUs, each line alone on its GPU
# (Warp planners): PushT-Fixed and -Rand open loop (all planners), the PushT-Obs suite (PACHS's
# default and the parallel rollout), and Warp against MuJoCo C on policy pushes. MuJoCo Warp's
# kernels are compiled once first, so that no timed call includes it.
#   OUT=dir bash experiments/results/faithful_gpu/run.sh
set -u
o=$OUT/r; mkdir -p "$o"
here=experiments/results/faithful_gpu
OL="python3 experiments/open_loop.py --backend warp"
$OL --task pusht-obs --layout slot --planners pachs-improve --instances 1 --rounds 1 \
  --budget 2000 --out /tmp/warp_kernels.json > "$o/warp_kernels.log" 2>&1
cat > /tmp/jobs <<JOBS
$OL --task pusht-fixed --planners pachs,single,parallel,beam --out $o/pusht-fixed.json && $OL --task pusht-rand --planners pachs,single,parallel,beam --out $o/pusht-rand.json && python3 experiments/physics_agreement.py agreement --layouts gate,wall,slot,detour,two-gaps --instances 16 --steps 40 --planners warp --candidates today --out $o/agreement.json
for L in gate wall detour slot two-gaps; do $OL --task pusht-obs --layout \$L --planners pachs-improve,parallel --out $o/\$L.json; done
JOBS
bash experiments/parallel_gpus.sh /tmp/jobs "$o/logs" "${LIMIT_S:-450}"
cd "$OUT" && tar czf faithful.tgz r && rm -rf r
