#!/bin/sh
# Regenerates the gmsh fixtures of the mesh-reader tests (gmsh 4.8.4 used).
# Each geometry is meshed as 4-node (order 1) and 10-node (order 2) tets and
# saved in the four formats the reader supports: MSH 2.2 / 4.1, ASCII / binary.
set -e
cd "$(dirname "$0")"
for geo in cube sphere; do
  for order in 1 2; do
    if [ "$order" = 1 ]; then kind=tet4; else kind=tet10; fi
    for fmt in msh22 msh41; do
      gmsh -3 -order "$order" "$geo.geo" -format "$fmt" -o "${geo}_${kind}_${fmt}_ascii.msh" > /dev/null
      gmsh -3 -order "$order" "$geo.geo" -format "$fmt" -bin -o "${geo}_${kind}_${fmt}_bin.msh" > /dev/null
    done
  done
done
