#!/usr/bin/env bash
# The ablation rows of the README/BENCHMARKS tables on one sequence (issue 15): ORB-SLAM2
# mode, DynaPix as shipped before the real-data work (the paper's terms on an ORB-SLAM2 first
# pass, one weighted pass, no safeguards), DynaPix now, and DynaPix with one part switched off
# or added at a time. No ground truth at run time except the `oracle` row.
#
#   scripts/ablations.sh SEQ OUT [ROW...]     (default: every row)
#
# Runs go to OUT/runs/<sequence name>/<row>/ (run.json, trajectory.txt, earlier passes);
# OUT/table.md holds one line per row with the motionless floor.
set -euo pipefail
SEQ=${1:?usage: scripts/ablations.sh SEQ OUT [ROW...]}
OUT=${2:?usage: scripts/ablations.sh SEQ OUT [ROW...]}
shift 2
here=$(cd "$(dirname "$0")/.." && pwd)
bin="$here/target/release/dynapix"
[ -x "$bin" ] || (cd "$here" && cargo build --release -q)
name=$(basename "$SEQ")
mkdir -p "$OUT/runs/$name" "$OUT/config"
cat > "$OUT/config/shipped.yaml" <<'YAML'
# DynaPix as shipped before the real-data work: the paper's terms, ORB-SLAM2 first pass, one
# weighted pass, no static-feature mask, no predicted tracking, no final pose refinement.
motion:
  cues: {paper: true, geometric: false, rigidity: false}
passes: {first: orbslam2, weighted: 1}
slam:
  params:
    static_features_min_weight: null
    tracking: {predicted_frames: 0}
    final_pose_refinement: false
YAML
echo 'slam: {params: {static_features_min_weight: null}}' > "$OUT/config/no_static_features.yaml"
echo 'slam: {params: {tracking: {predicted_frames: 0}}}' > "$OUT/config/no_predicted.yaml"
echo 'slam: {params: {final_pose_refinement: false}}' > "$OUT/config/no_final_refinement.yaml"
echo 'motion: {rigidity: {flow_working_width: 0}}' > "$OUT/config/flow_full_level.yaml"
echo 'motion: {rigidity: {shared_pairs: false}}' > "$OUT/config/own_pair_flows.yaml"
declare -A ROWS=(
  [orbslam2]="--method orbslam2"
  [dynapix_shipped]="--method dynapix --config $OUT/config/shipped.yaml"
  [dynapix]="--method dynapix"
  [plus_paper_terms]="--method dynapix --cues paper,geometric,rigidity"
  [no_geometric]="--method dynapix --cues rigidity"
  [no_rigidity_cue]="--method dynapix --cues geometric"
  [orbslam2_first_pass]="--method dynapix --first-pass orbslam2"
  [one_pass]="--method dynapix --passes 1"
  [three_passes]="--method dynapix --passes 3"
  [no_static_features]="--method dynapix --config $OUT/config/no_static_features.yaml"
  [no_predicted_tracking]="--method dynapix --config $OUT/config/no_predicted.yaml"
  [no_final_refinement]="--method dynapix --config $OUT/config/no_final_refinement.yaml"
  [flow_full_level]="--method dynapix --config $OUT/config/flow_full_level.yaml"
  [own_pair_flows]="--method dynapix --config $OUT/config/own_pair_flows.yaml"
  [oracle_poses]="--method dynapix --oracle-poses"
)
ORDER="orbslam2 dynapix_shipped dynapix plus_paper_terms no_geometric no_rigidity_cue orbslam2_first_pass one_pass three_passes no_static_features no_predicted_tracking no_final_refinement flow_full_level own_pair_flows oracle_poses"
for row in ${*:-$ORDER}; do
  dir="$OUT/runs/$name/$row"
  [ -f "$dir/run.json" ] && continue
  start=$(date +%s)
  # shellcheck disable=SC2086
  "$bin" run "$SEQ" ${ROWS[$row]} --out "$dir" --cache "$OUT/cache/$name" -q | grep 'ATE' | sed "s|^|$name $row: |"
  echo "$(( $(date +%s) - start ))" > "$dir/wall_seconds.txt"
done
python3 "$here/scripts/evidence_table.py" "$OUT/runs" > "$OUT/table.md"
cat "$OUT/table.md"
