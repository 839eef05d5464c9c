"""Monte Carlo seeds fit Mitsuba's 32-bit sampler seeds for any run seed (seed * 1000003 + k alone overflows from
seed 4295 on)."""

from swim.validation.mitsuba import wavefront_seed


def test_wavefront_seeds_fit_32_bits_and_keep_small_seeds_unchanged():
    for seed in (0, 1, 4294, 4295, 10**6, 2**40):
        for k in (0, 1, 77):
            assert 0 <= wavefront_seed(seed, k) < 2**32
    # below the wrap the seeds are those the cached references were made with
    assert wavefront_seed(1, 3) == 1 * 1000003 + 3
    assert len({wavefront_seed(5000, k) for k in range(1000)}) == 1000
