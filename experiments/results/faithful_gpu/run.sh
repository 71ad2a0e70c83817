#!/usr/bin/env bash
# The shipped models on the faithful physics, one host of 4 GPUs, each line alone on its GPU
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
$OL --task pusht-fixed --out $o/pusht-fixed.json && $OL --task pusht-rand --out $o/pusht-rand.json
for L in slot gate; do $OL --task pusht-obs --layout \$L --planners pachs-improve,parallel --out $o/\$L.json; done
for L in wall two-gaps; do $OL --task pusht-obs --layout \$L --planners pachs-improve,parallel --out $o/\$L.json; done
$OL --task pusht-obs --layout detour --planners pachs-improve,parallel --out $o/detour.json; python3 experiments/physics_agreement.py agreement --layouts gate,wall,slot,detour,two-gaps --instances 16 --steps 40 --planners warp --candidates today --out $o/agreement.json
JOBS
bash experiments/parallel_gpus.sh /tmp/jobs "$o/logs" "${LIMIT_S:-450}"
cd "$OUT" && tar czf faithful.tgz r && rm -rf r
