# job C: two-gaps again (compaction default and four sizes), detour, slot, wall-right, gate with four sizes
source experiments/results/default_gpu_runs/common.sh
C4=0.5,0.25,0.125,0.015625
LABEL=two-gaps_c4_again wall $OL --layout two-gaps --planners pachs-improve,parallel --compact-fractions $C4 --out $O/two-gaps_c4_again.json > $O/a1.log 2>&1
LABEL=two-gaps_again wall $OL --layout two-gaps --planners pachs-improve --out $O/two-gaps_again.json > $O/a2.log 2>&1
summ $O/two-gaps_c4_again.json $O/two-gaps_again.json
for L in detour slot gate; do
  LABEL=${L}_c4 wall $OL --layout $L --planners pachs-improve,parallel --compact-fractions $C4 --out $O/${L}_c4.json > $O/$L.log 2>&1; summ $O/${L}_c4.json; done
LABEL=wall-right_c4 wall $HO --layout wall-right --planners pachs-improve,parallel --compact-fractions $C4 --out $O/wall-right_c4.json > $O/wr.log 2>&1; summ $O/wall-right_c4.json
cd $OUT && tar czf c.tgz r && rm -rf r
