"""Data association: nearest neighbour with the eq. (49) gate, conflicts, JCBB."""

from __future__ import annotations

import numpy as np

from auvgw.slam.landmark.association import (
    JCBB,
    NearestNeighbour,
    jcbb,
    resolve_conflicts,
)
from auvgw.slam.landmark.ekfslam import EKFSLAM
from auvgw.slam.landmark.fastslam import FastSLAM1
from auvgw.slam.models import BicycleModel, RangeBearing


def test_nn_picks_nearest_and_gates():
    nn = NearestNeighbour(gate_accept=9.21, gate_new=25.0)
    d = np.array([[3.0, 0.5, 40.0], [30.0, 50.0, 26.0], [12.0, 11.0, 30.0]])
    slots, best = nn.assign(d)
    assert slots.tolist() == [1, -1, -2]  # match, new feature, ambiguous (ignored)
    np.testing.assert_allclose(best, [0.5, 26.0, 11.0])


def test_conflicts_leave_the_landmark_to_the_closest_observation():
    slots = np.array([[2, 2, 0, -1], [1, 1, 1, -2]])
    best = np.array([[4.0, 1.0, 0.3, 99.0], [0.2, 0.1, 0.3, 12.0]])
    out = resolve_conflicts(slots, best)
    assert out.tolist() == [[-2, 2, 0, -1], [-2, 1, -2, -2]]


def particle_filter_with_map(landmarks):
    f = FastSLAM1(
        BicycleModel(),
        RangeBearing(),
        np.zeros((2, 2)),
        np.diag([0.01, 3e-4]),
        n_particles=4,
        association=NearestNeighbour(),
    )
    obs = RangeBearing()
    z = obs.h(np.zeros(3), landmarks)
    f.update(z, np.random.default_rng(0))  # empty map: every observation starts a landmark
    return f


def test_particles_associate_the_right_landmarks_and_start_new_ones():
    lms = np.array([[10.0, 0.0], [12.0, 5.0], [8.0, -6.0]])
    f = particle_filter_with_map(lms)
    assert f.n_lm.tolist() == [3, 3, 3, 3]
    obs = RangeBearing()
    seen = np.array([[8.0, -6.0], [10.0, 0.0], [20.0, 20.0]])  # two known (reordered), one new
    z = obs.h(np.zeros(3), seen) + np.array([0.05, 0.005])
    slots = f._associate(z, None)
    assert slots.tolist() == [[2, 0, -1]] * 4
    # 0.5 m off landmark 0: outside the acceptance gate, too close for a new landmark: ignored
    outlier = obs.h(np.zeros(3), np.array([[10.5, 0.2]]))
    assert f._associate(outlier, None).tolist() == [[-2]] * 4
    f.update(z, np.random.default_rng(1))
    assert f.n_lm.tolist() == [4, 4, 4, 4]
    np.testing.assert_allclose(f.mu[0, 3], [20.0, 20.0], atol=2.0)


def ambiguous_ekf(association):
    """Three landmarks 2 m apart across the track, the pose very uncertain across track: every
    observation is individually compatible with every landmark."""
    f = EKFSLAM(
        BicycleModel(),
        RangeBearing(),
        np.zeros((2, 2)),
        np.diag([0.01, 1e-4]),
        association=association,
    )
    for y in (0.0, 2.0, 4.0):
        f._add(RangeBearing().h(np.zeros(3), np.array([10.0, y])), None)
    k = 3 + 2 * f.n_lm
    f.p[:k, :k] = np.eye(k) * 1e-4
    f.p[1, 1] = 9.0  # sigma_y = 3 m
    true_pose = np.array([0.0, -1.2, 0.0])  # the vehicle is really 1.2 m to the -y side
    z = RangeBearing().h(true_pose, np.array([[10.0, 0.0], [10.0, 2.0], [10.0, 4.0]]))
    return f, z


def test_jcbb_resolves_the_ambiguity_that_fools_nearest_neighbour():
    f, z = ambiguous_ekf(NearestNeighbour(gate_accept=9.21, gate_new=25.0))
    nn = f._associate(z, None)
    assert nn.tolist() != [0, 1, 2]  # individually, each observation looks like its neighbour
    f, z = ambiguous_ekf(JCBB())
    assert f._associate(z, None).tolist() == [0, 1, 2]


def test_jcbb_leaves_an_incompatible_observation_unpaired():
    # one landmark, two observations: the one that is far off is not paired
    v = np.array([[[0.1, 0.0]], [[5.0, 0.0]]])
    hph = np.zeros((1, 2, 1, 2))
    pairing, nis = jcbb(v, hph, np.eye(2) * 0.01, np.array([[True], [True]]))
    assert pairing.tolist() == [0, -1]
    np.testing.assert_allclose(nis, 1.0)
