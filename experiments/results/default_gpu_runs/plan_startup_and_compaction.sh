# job A: pachs plan first/cold/warm on a fresh machine; two-gaps and wall with two compaction settings
source experiments/results/default_gpu_runs/common.sh
W="plan --task pusht-obs"
ls ~/.cache/warp 2>&1 | head -2
LABEL=plan_first_on_fresh_machine wall plain $W > $O/plan_first.txt 2> $O/plan_first.err
rm -rf ~/.cache/pachs_jax .jaxcache
LABEL=plan_cold wall plain $W > $O/plan_cold.txt 2>&1
for i in 1 2 3; do LABEL=plan_warm$i wall plain $W > $O/plan_warm$i.txt 2>&1; done
tail -n 3 $O/plan_*.txt
C4=0.5,0.25,0.125,0.015625
LABEL=two-gaps wall $OL --layout two-gaps --planners pachs-improve,parallel --out $O/two-gaps.json > $O/two-gaps.log 2>&1
LABEL=two-gaps_c4 wall $OL --layout two-gaps --planners pachs-improve --compact-fractions $C4 --out $O/two-gaps_c4.json > $O/two-gaps_c4.log 2>&1
summ $O/two-gaps.json $O/two-gaps_c4.json
LABEL=wall wall $OL --layout wall --planners pachs-improve,parallel --out $O/wall.json > $O/wall.log 2>&1
LABEL=wall_c4 wall $OL --layout wall --planners pachs-improve --compact-fractions $C4 --out $O/wall_c4.json > $O/wall_c4.log 2>&1
summ $O/wall.json $O/wall_c4.json
cd $OUT && tar czf a.tgz r && rm -rf r
