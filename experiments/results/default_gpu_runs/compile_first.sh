# job D: search walls with every program compiled first: compaction default vs four sizes
source experiments/results/default_gpu_runs/common.sh
C4=0.5,0.25,0.125,0.015625
LABEL=warmup wall plain plan --task pusht-obs --instances 0-1 --budget 2000 > $O/warmup.txt 2>&1
for L in two-gaps slot gate; do
  LABEL=${L}_cf wall $OL --layout $L --planners pachs-improve,parallel --out $O/${L}_cf.json > $O/${L}_cf.log 2>&1
  LABEL=${L}_cf_c4 wall $OL --layout $L --planners pachs-improve --compact-fractions $C4 --out $O/${L}_cf_c4.json > $O/${L}_cf_c4.log 2>&1
  summ $O/${L}_cf.json $O/${L}_cf_c4.json
  (cd $OUT && tar czf d.tgz r/*.json r/walls.txt)
done
(cd $OUT && tar czf d.tgz r && rm -rf r)
