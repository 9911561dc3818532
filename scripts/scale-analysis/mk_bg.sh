#!/bin/bash
# mk_bg.sh SYNTH_DIR OUT_DIR: a view of a synthetic sequence without movers (background/ and
# depth_bg/ as the input images), same ground truth and camera: camera motion only.
mkdir -p "$2"; cp "$1/camera.yaml" "$1/groundtruth.txt" "$2/"
ln -sfn "$(realpath "$1")/background" "$2/background"; ln -sfn "$(realpath "$1")/depth_bg" "$2/depth_bg"
sed 's# rgb/# background/#; s# depth/# depth_bg/#' "$1/association.txt" > "$2/association.txt"
