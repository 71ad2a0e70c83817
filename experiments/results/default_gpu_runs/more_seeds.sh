# job B: the default on more search seeds (issue 33): detour instance set 1, gate, gate-mirror; $CF: compaction
# run as: CF=0.5,0.25,0.125,0.015625 bash experiments/results/default_gpu_runs/more_seeds.sh
source experiments/results/default_gpu_runs/common.sh
CF=${CF:-0.125,0.015625}
for s in 1 2; do
  LABEL=detour_set1_seed$s wall $OL --layout detour --instance-seed 1 --seed $s --compact-fractions $CF --planners pachs-improve,parallel --out $O/detour_set1_seed$s.json > $O/detour_set1_seed$s.log 2>&1
  summ $O/detour_set1_seed$s.json
done
for s in 1 2; do
  LABEL=gate_seed$s wall $OL --layout gate --seed $s --compact-fractions $CF --planners pachs-improve,parallel --out $O/gate_seed$s.json > $O/gate_seed$s.log 2>&1
  LABEL=gate-mirror_seed$s wall $HO --layout gate-mirror --seed $s --compact-fractions $CF --planners pachs-improve,parallel --out $O/gate-mirror_seed$s.json > $O/gate-mirror_seed$s.log 2>&1
  summ $O/gate_seed$s.json $O/gate-mirror_seed$s.json
done
cd $OUT && tar czf b.tgz r && rm -rf r
