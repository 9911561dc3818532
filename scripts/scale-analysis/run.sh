#!/bin/bash
# usage: run.sh SEQ TAG [extra slam args]
seq=$1; tag=$2; shift 2
B=${BIN:-target/release/dynapix}; D=${DATA:-/tmp/scale}
$B slam $D/$seq --out $D/o_${seq}_$tag --no-loop-closing "$@" > $D/log_${seq}_$tag 2>&1
$B eval --gt $D/$seq/groundtruth.txt --est $D/o_${seq}_$tag/trajectory.txt --sim3 --json | python3 -c "import json,sys; d=json.load(sys.stdin); print('$seq $tag ate=%.4f scale=%.5f pairs=%d'%(d['ate_rmse_m'],d['alignment_scale'],d['pairs']))"
