#!/bin/sh
# Issue 28's held-out study, part 2 (after run.sh): the paper's density (Figs. 15-17) and
# open-loop (Fig. 12) claims on the test seed 1028, parameters frozen at commit c519484.
set -e
OUT=docs/results/magnetic/heldout
E="auvgw slam eval --pipeline magnetic --runs 20 --jobs 1 --seed 1028 --no-progress"
$E --scenario config/scenarios/beacons_dense.json --variant default --variant density=first-half --algorithms amb-slam,mb-slam,mb-slam-fej,dr --out $OUT/dense_density
$E --scenario config/scenarios/beacons_amb.json --variant loop=open --algorithms amb-slam --out $OUT/paper_open_loop
# a held-out layout (make_layout.py, written after the first runs; same frozen parameters)
$E --scenario config/scenarios/beacons_amb_layout2.json --algorithms amb-slam,acoustic-only,mb-slam,mb-slam-fej,dr --out $OUT/layout2
