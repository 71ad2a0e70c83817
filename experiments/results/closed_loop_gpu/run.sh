#!/usr/bin/env bash
# The closed loop on PushT-Obs (Warp planners, MuJoCo C worlds unless the variant says
# otherwise), one line of runs per GPU of the host, each line alone on its GPU, one run after
# another, all within one device command (570 s): 20 instances x 5 rounds per run.
# A run is LAYOUT/VARIANT; a variant is a planner, pachs (replan.Session, the search's path
# and the last answer's remainder replayed in its search, by default; K the task's for the
# query time) or parallel (the parallel rollout), then options joined by '-': remainder, policy
# (the session's candidates), k<N> (N edges per iteration), q<S> (S seconds per query),
# planner-world (the plans executed in the planners' own physics), nofill (a short answer is
# not followed by policy actions: the next query comes sooner), guard / noguard (the policy
# fill after a short answer is / is not stopped before the first edge the planner's physics
# finds invalid: closed_loop.py --fill-check 1 / 0; by default the task's for the query time),
# soft (the soft-blocks physics preset, planners and worlds: the screens in the results'
# ledger), check (each answer executed up to the first action one of 8 perturbed copies of
# its start could not take: closed_loop.py --check-copies 8), h<N> (edges of N transitions),
# trace (also each planner's episodes, world states, actions and PACHS's planned states:
# <run>.<planner>.trace.npz).
# A line is a comma-separated list of runs (the results' runs: 2 to 4 GPUs a command):
#   OUT=dir bash experiments/results/closed_loop_gpu/run.sh 'wall/pachs,wall/pachs-k256' \
#     'wall/parallel,wall/pachs-remainder-policy'
# A one-episode call first compiles MuJoCo Warp's kernels, so that no measured query does
# (WARM=0 leaves it to each run's first query, before its clock). EXTRA: more closed_loop.py
# flags for every run. GPU_OFFSET=n: the lines start at GPU n (beside another job script).
# BUDGET_S counts from T0 (epoch seconds; default: this script's start): set T0=$(date +%s)
# first in the device command, so that the wheels' install on a fresh machine (up to a minute)
# counts too and the results' tarball is written before the command's limit.
set -u
if [ "$#" -lt 1 ]; then
  echo "usage: OUT=dir bash $0 RUNS [RUNS ...] (one line per GPU; a run: LAYOUT/VARIANT)" >&2
  exit 2
fi
END=$((${T0:-$(date +%s)} + ${BUDGET_S:-570}))  # the device tool's 600 s, less packing
o=$OUT/r; mkdir -p "$o"
CL="python3 experiments/heldout_layouts.py experiments/closed_loop.py --task pusht-obs --backend ${BACKEND:-warp} ${EXTRA:-}"
if [ "${WARM:-1}" = 1 ]; then  # each physics the runs use
  physics=('')
  case " $* " in *-soft*) physics+=(soft-blocks) ;; esac
  for p in "${physics[@]}"; do
    CUDA_VISIBLE_DEVICES=${GPU_OFFSET:-0} $CL --layout gate --planners pachs --instances 1 \
      --rounds 1 --max-queries 2 ${p:+--physics $p} --out /tmp/warp_kernels.json \
      >> "$o/warp_kernels.log" 2>&1
  done
fi
run() {  # the command line of one run
  local layout=${1%%/*} variant=${1#*/} flags=()
  local planner=${variant%%-*} opts=${variant#*-}
  [ "$opts" = "$variant" ] && opts=''
  case $planner in
    pachs|parallel) flags+=(--planners "$planner") ;;
    *) echo "echo unknown planner $planner"; return ;;
  esac
  local candidates=()
  for opt in ${opts//-/ }; do
    case $opt in
      remainder|policy) candidates+=("$opt") ;;
      k[0-9]*) flags+=(-K "${opt#k}") ;;
      q[0-9]*) flags+=(--query-time "${opt#q}") ;;
      planner|world) [ "$opt" = world ] && flags+=(--world planner) ;;
      nofill) flags+=(--fill-with-policy 0) ;;
      guard) flags+=(--fill-check 1) ;;
      noguard) flags+=(--fill-check 0) ;;
      soft) flags+=(--physics soft-blocks) ;;
      check) flags+=(--check-copies 8) ;;
      h[0-9]*) flags+=(-H "${opt#h}") ;;
      trace) flags+=(--trace 1) ;;
      *) echo "echo unknown option $opt"; return ;;
    esac
  done
  flags+=(--candidates "'$(IFS=,; echo "${candidates[*]}")'")
  echo "$CL --layout $layout ${flags[*]} --out $o/${layout}_$variant.json" \
       "> $o/${layout}_$variant.log 2>&1; echo $1; tail -c 900 $o/${layout}_$variant.log"
}
export -f run; export CL o
left=$((END - $(date +%s))); [ "$left" -gt 0 ] || left=1  # 0 would mean no limit
bash experiments/parallel_gpus.sh --lines run "$o/logs" "$left" "$@"
cd "$OUT" && tar czf closed_loop.tgz r && rm -rf r
