# sourced by the GPU jobs: output folder, a timer and the plain `pachs` command
O=$OUT/r; mkdir -p $O
wall() { local t0=$(date +%s%N); "$@"; local rc=$?; echo "WALL_MS $(( ($(date +%s%N)-t0)/1000000 )) rc $rc: $LABEL" | tee -a $O/walls.txt >&2; }
plain() { python3 -c "from pachs_jax.cli import run; import sys; sys.argv=['pachs']+sys.argv[1:]; run()" "$@"; }
OL="python3 experiments/open_loop.py --task pusht-obs --backend warp"
HO="python3 experiments/heldout_layouts.py experiments/open_loop.py --task pusht-obs --backend warp"
summ() { python3 - "$@" <<'PY'
import json, sys
for f in sys.argv[1:]:
    try: d = json.load(open(f))
    except Exception as e: print(f, 'missing', e); continue
    print(f.split('/')[-1], [(s['planner'], s['successes'], round(s['batch_wall_s'], 2), round(s.get('cost_success_mean') or 0, 1)) for s in d['summary']], flush=True)
PY
}
