#!/bin/sh
# The density study of run2.sh again after commit "density change table carries 95 % bootstrap
# intervals" (reporting only; same seed, same parameters, so the same runs and RMSEs).
set -e
OUT=docs/results/magnetic/heldout
E="auvgw slam eval --pipeline magnetic --runs 20 --jobs 1 --seed 1028 --no-progress"
$E --scenario config/scenarios/beacons_dense.json --variant default --variant density=first-half --algorithms amb-slam,mb-slam,mb-slam-fej,dr --out $OUT/dense_density
