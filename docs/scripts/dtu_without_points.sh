#!/usr/bin/env bash
# Sourced by the study scripts: `dtu_without_points SRC DEST` writes dtu_scan24 without its
# points into DEST: the same cameras and images, an empty points3D.txt and no 2-D
# observations (each image's second line emptied), as a COLMAP export without SfM points.
dtu_without_points() {
  local src=$1 nop=$2
  mkdir -p "$nop/sparse/0"
  cp "$src/sparse/0/cameras.txt" "$nop/sparse/0/cameras.txt"
  awk '/^#/ { print; next } { if (++n % 2 == 1) print; else print "" }' \
    "$src/sparse/0/images.txt" >"$nop/sparse/0/images.txt"
  printf '# 3D point list with one line of data per point:\n# Number of points: 0\n' \
    >"$nop/sparse/0/points3D.txt"
  [ -d "$nop/images" ] || cp -r "$src/images" "$nop/images"   # inputs must be plain files
}
