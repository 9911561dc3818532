#!/usr/bin/env bash
# Independent check of `dynapix eval` against evo (PyPI `evo`, `evo_ape tum GT EST -a`):
# ATE RMSE after SE(3) alignment on the reference trajectories of ../shared/data.
# evo associates within 0.01 s by default; the TUM tools (and dynapix) use 0.02 s, so evo
# gets `--t_max_diff 0.02`. evo pairs each pose with its nearest neighbour, while the TUM
# associate.py (and dynapix) match greedily by smallest |dt| over all candidate pairs; the two
# agree on the five golden trajectories but not on fr2_desk ORB (2225 vs 2223 pairs), so that
# row is shown for information and checked only against an inline transcription of the TUM
# tool (column "tum_rmse"), which every row must match.
# Creates a local venv (.venv) on first use; needs python3 with venv and network for pip.
# Fails when any RMSE differs by more than 1e-6 m.
#
# Usage: scripts/check-ate-evo.sh            (from the repository root)
set -euo pipefail

root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
data="${DYNAPIX_DATA:-$root/../shared/data}"
tol=1e-6

if [ ! -d "$data" ]; then
  echo "data folder $data not found (set DYNAPIX_DATA)" >&2
  exit 2
fi

if [ ! -x .venv/bin/evo_ape ]; then
  python3 -m venv .venv
  .venv/bin/pip install --quiet --upgrade pip
  .venv/bin/pip install --quiet evo
fi
cargo build --release -p dynapix-cli --quiet
dynapix="$root/target/release/dynapix"

walk="$data/tum-walking-meta"
ref="$data/reference-trajectories"
pairs=(
  "walking_xyz|$walk/rgbd_dataset_freiburg3_walking_xyz/groundtruth.txt|$ref/dynaslam_rerun_yubaoliu/fr3_walk_xyz_CameraTrajectory.txt"
  "walking_static|$walk/rgbd_dataset_freiburg3_walking_static/groundtruth.txt|$ref/dynaslam_rerun_yubaoliu/fr3_walk_static_CameraTrajectory.txt"
  "walking_rpy|$walk/rgbd_dataset_freiburg3_walking_rpy/groundtruth.txt|$ref/dynaslam_rerun_yubaoliu/fr3_walk_rpy_CameraTrajectory.txt"
  "walking_halfsphere|$walk/rgbd_dataset_freiburg3_walking_halfsphere/groundtruth.txt|$ref/dynaslam_rerun_yubaoliu/fr3_walk_halfsphere_CameraTrajectory.txt"
  "fr1_xyz_rgbdslam|$ref/evo_testdata/freiburg1_xyz-groundtruth.txt|$ref/evo_testdata/freiburg1_xyz-rgbdslam.txt"
  "fr2_desk_orb|$ref/evo_testdata/fr2_desk_groundtruth.txt|$ref/evo_testdata/fr2_desk_ORB.txt|info"
)

tum_ate() {
  .venv/bin/python - "$1" "$2" <<'PY'
import bisect, sys, numpy
def read(fn):
    d = {}
    for line in open(fn).read().replace(",", " ").replace("\t", " ").split("\n"):
        if line and line[0] != "#":
            v = [x for x in line.split(" ") if x]
            if len(v) > 1:
                d[float(v[0])] = v[1:]
    return d
a, b = read(sys.argv[1]), read(sys.argv[2])
kb = sorted(b)
cand = []
for x in a:
    i = bisect.bisect_left(kb, x - 0.03)
    while i < len(kb) and kb[i] < x + 0.03:
        if abs(x - kb[i]) < 0.02:
            cand.append((abs(x - kb[i]), x, kb[i]))
        i += 1
cand.sort()
ua, ub, m = set(), set(), []
for _, x, y in cand:
    if x not in ua and y not in ub:
        ua.add(x); ub.add(y); m.append((x, y))
m.sort()
G = numpy.array([[float(v) for v in a[x][0:3]] for x, _ in m]).T
E = numpy.array([[float(v) for v in b[y][0:3]] for _, y in m]).T
mz, dz = E - E.mean(1, keepdims=True), G - G.mean(1, keepdims=True)
U, _, Vh = numpy.linalg.svd((mz @ dz.T).T)
S = numpy.eye(3)
if numpy.linalg.det(U) * numpy.linalg.det(Vh) < 0:
    S[2, 2] = -1
R = U @ S @ Vh
t = G.mean(1, keepdims=True) - R @ E.mean(1, keepdims=True)
err = numpy.sqrt(((R @ E + t - G) ** 2).sum(0))
print("%.12f %d" % (numpy.sqrt((err ** 2).mean()), len(m)))
PY
}

tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
fail=0
printf '%-20s %14s %6s %14s %6s %14s %6s %9s\n' sequence evo_rmse pairs tum_rmse pairs dynapix_rmse pairs diff_evo
for entry in "${pairs[@]}"; do
  IFS='|' read -r name gt est mode <<<"$entry"
  .venv/bin/evo_ape tum "$gt" "$est" -a --t_max_diff 0.02 --save_results "$tmp/$name.zip" --no_warnings >/dev/null
  evo_json="$(.venv/bin/python - "$tmp/$name.zip" <<'PY'
import json, sys, zipfile
z = zipfile.ZipFile(sys.argv[1])
stats = json.loads(z.read("stats.json"))
# One timestamp per matched pose pair.
import io, numpy as np
n = len(np.load(io.BytesIO(z.read("timestamps.npy"))))
print(f"{stats['rmse']:.12f} {n}")
PY
)"
  read -r evo_rmse evo_pairs <<<"$evo_json"
  dp_json="$("$dynapix" eval --json --gt "$gt" --est "$est")"
  read -r dp_rmse dp_pairs <<<"$(python3 -c 'import json,sys; d=json.loads(sys.argv[1]); print("%.12f %d" % (d["ate_rmse_m"], d["pairs"]))' "$dp_json")"
  read -r tum_rmse tum_pairs <<<"$(tum_ate "$gt" "$est")"
  diff="$(python3 -c "print(f'{abs($evo_rmse-$dp_rmse):.2e}')")"
  printf '%-20s %14s %6s %14s %6s %14s %6s %9s\n' "$name" "$evo_rmse" "$evo_pairs" \
    "$tum_rmse" "$tum_pairs" "$dp_rmse" "$dp_pairs" "$diff"
  if ! python3 -c "import sys; sys.exit(0 if abs($tum_rmse-$dp_rmse) <= $tol else 1)" \
    || [ "$tum_pairs" != "$dp_pairs" ]; then
    echo "  MISMATCH: dynapix differs from the TUM transcription" >&2
    fail=1
  fi
  if [ "$mode" = "info" ]; then
    echo "  (info only: evo's nearest-neighbour association differs from TUM's greedy one here)"
  elif ! python3 -c "import sys; sys.exit(0 if abs($evo_rmse-$dp_rmse) <= $tol else 1)" \
    || [ "$evo_pairs" != "$dp_pairs" ]; then
    echo "  MISMATCH: |evo - dynapix| > $tol or different pair count" >&2
    fail=1
  fi
done
echo
echo "With scale (evo_ape -as vs dynapix eval --sim3):"
printf '%-20s %14s %14s %9s\n' sequence evo_rmse dynapix_rmse diff
for entry in "${pairs[@]}"; do
  IFS='|' read -r name gt est mode <<<"$entry"
  [ "$mode" = "info" ] && continue
  .venv/bin/evo_ape tum "$gt" "$est" -as --t_max_diff 0.02 --save_results "$tmp/$name-sim3.zip" \
    --no_warnings >/dev/null
  evo_rmse="$(.venv/bin/python -c 'import json,sys,zipfile; print("%.12f" % json.loads(zipfile.ZipFile(sys.argv[1]).read("stats.json"))["rmse"])' "$tmp/$name-sim3.zip")"
  dp_rmse="$("$dynapix" eval --json --sim3 --gt "$gt" --est "$est" | python3 -c 'import json,sys; print("%.12f" % json.load(sys.stdin)["ate_rmse_m"])')"
  diff="$(python3 -c "print(f'{abs($evo_rmse-$dp_rmse):.2e}')")"
  printf '%-20s %14s %14s %9s\n' "$name" "$evo_rmse" "$dp_rmse" "$diff"
  if ! python3 -c "import sys; sys.exit(0 if abs($evo_rmse-$dp_rmse) <= $tol else 1)"; then
    echo "  MISMATCH: |evo - dynapix| > $tol (Sim3)" >&2
    fail=1
  fi
done
if [ "$fail" -ne 0 ]; then
  echo "FAILED: dynapix eval differs from evo_ape" >&2
  exit 1
fi
echo "OK: dynapix eval matches evo_ape -a / -as (golden rows) and the TUM transcription (all rows) within $tol m"
