# The closed loop on PushT-Obs (one GPU, Warp planners, MuJoCo C worlds unless the variant says
# otherwise), each planner alone on the GPU, one after another: 20 instances x 5 rounds.
# Items LAYOUT/VARIANT; variants: pachs (replan.Session, its default candidates), pachs-alone
# (the search's path alone), parallel (the parallel rollout), and any of
# them with '-planner-world' (the plans executed in the planners' own physics).
# A one-episode call first compiles MuJoCo Warp's kernels, so that no measured query does.
# run as: bash experiments/results/closed_loop_gpu/run.sh detour/pachs detour/parallel ...
source experiments/results/default_gpu_runs/common.sh
python3 -m compileall -q -j 16 /tmp/site > /dev/null 2>&1
END=$((SECONDS + ${BUDGET_S:-570}))
CL="python3 experiments/heldout_layouts.py experiments/closed_loop.py --task pusht-obs --backend ${BACKEND:-warp}"
[ "${WARM:-1}" = 1 ] && LABEL=warp_kernels wall $CL --layout gate --planners pachs --instances 1 --rounds 1 \
  --max-queries 2 --out /tmp/warp_kernels.json > $O/warp_kernels.log 2>&1
for item in "$@"; do
  L=${item%%/*}; V=${item#*/}; flags=()
  case $V in *-planner-world) flags+=(--world planner); V0=${V%-planner-world};; *) V0=$V;; esac
  case $V0 in
    pachs) flags+=(--planners pachs);;
    pachs-alone) flags+=(--planners pachs --candidates '');;
    parallel) flags+=(--planners parallel);;
    *) echo "unknown variant $V0"; continue;;
  esac
  LABEL=$L/$V wall timeout $((END - SECONDS)) $CL --layout $L "${flags[@]}" \
    $EXTRA --out $O/${L}_$V.json > $O/${L}_$V.log 2>&1
  python3 - $O/${L}_$V.json <<'PY'
import json, sys
try:
  d = json.load(open(sys.argv[1]))
except Exception as e:
  print(sys.argv[1], 'missing', e); sys.exit()
for s in d['summary']:
  print(sys.argv[1].split('/')[-1], s['successes'], '/', s['episodes'], 'evals/q',
        round(s['evaluations_per_query_mean'] or 0), 'it/q', s.get('iterations_per_query_mean'),
        'q_s', round(s['query_time_s_mean'] or 0, 3), 'answers', s.get('answers'),
        'empty_search', s.get('empty_search'), 'follow_s', s.get('follow_s_mean'), flush=True)
PY
done
cat $O/walls.txt
cd $OUT && tar czf r.tgz r && rm -rf r
