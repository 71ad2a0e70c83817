#!/usr/bin/env bash
# The shipped models on the faithful physics (Warp planners), one line of jobs per GPU of the
# host, each line alone on its GPU, all within one device command (570 s): PushT-Fixed and -Rand
# open loop (every planner), PushT-Obs layouts (PACHS's default and the parallel rollout), and
# Warp against MuJoCo C on policy pushes ('agreement'). MuJoCo Warp's kernels are compiled once
# first, so that no timed call includes them. A line is a comma-separated list of jobs:
#   OUT=dir bash experiments/results/faithful_gpu/run.sh 'tasks,agreement' 'gate,wall,detour'
# (the runs of the results: 2 GPUs; pusht-rand and wall were cut by the limit and ran again alone)
# GPU_OFFSET=n: the lines start at GPU n (beside another job script); BUDGET_S: the lines' limit;
# PHYSICS=soft-blocks: every job on that preset (the agreement: physics_agreement.py's
# candidate 'faithful', the same settings; unset: 'faithful margin3mm', the default's), packed
# as soft-blocks.tgz.
set -u
if [ "$#" -lt 1 ]; then
  echo "usage: OUT=dir bash $0 JOBS [JOBS ...] (one line per GPU; jobs: tasks, agreement," \
       "or a PushT-Obs layout)" >&2
  exit 2
fi
END=$((SECONDS + ${BUDGET_S:-570}))  # the device tool's 600 s, less packing
o=$OUT/r; mkdir -p "$o"
PHYSICS=${PHYSICS:-}
OL="python3 experiments/open_loop.py --backend warp ${PHYSICS:+--physics $PHYSICS}"
case $PHYSICS in
  '') candidate='faithful margin3mm' ;;
  soft-blocks) candidate=faithful ;;
  *) echo "run.sh: PHYSICS=$PHYSICS: faithful (unset) or soft-blocks" >&2; exit 2 ;;
esac
CUDA_VISIBLE_DEVICES=${GPU_OFFSET:-0} $OL --task pusht-obs --layout slot --planners pachs-improve --instances 1 --rounds 1 \
  --budget 2000 --out /tmp/warp_kernels.json > "$o/warp_kernels.log" 2>&1
job() {  # the command line of one job
  case $1 in
    tasks) echo "$OL --task pusht-fixed --planners pachs,single,parallel,beam" \
                "--out $o/pusht-fixed.json && $OL --task pusht-rand" \
                "--planners pachs,single,parallel,beam --out $o/pusht-rand.json" ;;
    agreement) echo "python3 experiments/physics_agreement.py agreement" \
                    "--layouts gate,wall,slot,detour,two-gaps --instances 16 --steps 40" \
                    "--planners warp --candidates '$candidate' --out $o/agreement.json" ;;
    *) echo "$OL --task pusht-obs --layout $1 --planners pachs-improve,parallel" \
            "--out $o/$1.json" ;;
  esac
}
export -f job; export OL o candidate
bash experiments/parallel_gpus.sh --lines job "$o/logs" $((END - SECONDS)) "$@"
cd "$OUT" && tar czf "${PHYSICS:-faithful}.tgz" r && rm -rf r
