#!/bin/bash
# usage: run2.sh SEQDIR TAG [slam args]  (loop closing on unless passed)
seq=$1; tag=$2; shift 2
B=${BIN:-target/release/dynapix}
o=${OUTDIR:-/tmp/scale}/o2_$(basename $seq)_$tag
$B slam $seq --out $o "$@" > $o.log 2>&1
$B eval --gt $seq/groundtruth.txt --est $o/trajectory.txt --sim3 --json | python3 -c "import json,sys; d=json.load(sys.stdin); print('$(basename $seq) $tag $* ate=%.4f scale=%.5f pairs=%d'%(d['ate_rmse_m'],d['alignment_scale'],d['pairs']))"
$B eval --gt $seq/groundtruth.txt --est $o/trajectory.txt --json | python3 -c "import json,sys; d=json.load(sys.stdin); print('   se3 ate=%.4f'%(d['ate_rmse_m']))"
