#!/bin/sh
# Issue 28's held-out study, part 4: the observability-constrained MB-SLAM (mb-slam-oc) on the
# test seed 1028, code frozen at the commit "FREEZE 2026-11-29T15:20Z" (nothing tuned: OC has no
# parameter; looked at only on tuning seed 0, 4 runs, beacons_dense / beacons_amb /
# beacons_amb_v03). mb-slam runs beside it: its numbers reproduce run.sh's / run2.sh's bit for
# bit, which shows the runs' random numbers are the same, so mb-slam-oc pairs with every
# algorithm of those directories (pair_oc.py). One process per row, one core each.
set -e
OUT=docs/results/magnetic/heldout
A=mb-slam,mb-slam-oc
E="auvgw slam eval --pipeline magnetic --runs 20 --jobs 1 --seed 1028 --no-progress"
$E --scenario config/scenarios/beacons_amb.json --algorithms $A --out $OUT/paper_oc &
$E --scenario config/scenarios/beacons_dense.json --algorithms $A --out $OUT/dense_oc &
$E --scenario config/scenarios/beacons_amb.json --variant track=mlp --algorithms $A --out $OUT/mlp_oc &
$E --scenario config/scenarios/beacons_amb_insdvl.json --algorithms $A --out $OUT/insdvl_oc &
$E --scenario config/scenarios/beacons_amb_layout2.json --algorithms $A --out $OUT/layout2_oc &
wait
