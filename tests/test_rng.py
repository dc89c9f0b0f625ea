import numpy as np

from swarmslam.runtime.matching.rng import normal, randint, seed_state, uniform


def draws(seed, n=1000):
    s = seed_state(seed)
    return np.array([uniform(s) for _ in range(n)])


def test_same_seed_same_stream_bit_for_bit():
    assert np.array_equal(draws(7), draws(7))
    assert not np.array_equal(draws(7), draws(8))


def test_uniform_is_uniform_on_unit_interval():
    u = draws(3, 20000)
    assert u.min() >= 0.0 and u.max() < 1.0
    hist, _ = np.histogram(u, bins=10, range=(0, 1))
    assert np.all(np.abs(hist - 2000) < 200)


def test_randint_covers_range_and_normal_moments():
    s = seed_state(5)
    ints = np.array([randint(s, 7) for _ in range(7000)])
    assert set(ints) == set(range(7))
    g = np.array([normal(s) for _ in range(20000)])
    assert abs(g.mean()) < 0.03 and abs(g.std() - 1) < 0.03
