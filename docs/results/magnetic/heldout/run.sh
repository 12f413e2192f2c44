#!/bin/sh
# Issue 28's held-out study: test seed 1028 (base seeds >= 1000 are held out), parameters frozen
# at commit c519484 (every filter, gate and MLP setting chosen before on seed 0). One process,
# one core. Run from the repository root: sh docs/results/magnetic/heldout/run.sh
set -e
OUT=docs/results/magnetic/heldout
ALL=amb-slam,acoustic-only,mb-slam,mb-slam-fej,dr
ACO=amb-slam,acoustic-only
USBL=acoustic_every=5,acoustic_sigma_m=0.5,acoustic_bearing_deg=1,acoustic_max_range_m=200
LBL=acoustic=range-only,acoustic_every=5,acoustic_sigma_m=0.5,acoustic_max_range_m=200
E="auvgw slam eval --pipeline magnetic --runs 20 --jobs 1 --seed 1028 --no-progress"
$E --scenario config/scenarios/beacons_amb.json --algorithms $ALL --out $OUT/paper
$E --scenario config/scenarios/beacons_dense.json --algorithms $ALL --out $OUT/dense
$E --scenario config/scenarios/beacons_amb.json --variant track=mlp --algorithms $ALL --out $OUT/mlp
$E --scenario config/scenarios/beacons_amb.json --variant $USBL --variant $LBL --algorithms $ACO --out $OUT/paper_acoustic
$E --scenario config/scenarios/beacons_amb_insdvl.json --algorithms $ALL --out $OUT/insdvl
$E --scenario config/scenarios/beacons_amb_insdvl.json --variant $USBL --variant $LBL --algorithms $ACO --out $OUT/insdvl_acoustic
$E --scenario config/scenarios/beacons_dense.json --variant $USBL --variant $LBL --algorithms $ACO --out $OUT/dense_acoustic
# added after the first part had run (same frozen parameters): the MLP track with INS + DVL navigation
$E --scenario config/scenarios/beacons_amb_insdvl.json --variant track=mlp --algorithms $ALL --out $OUT/insdvl_mlp
