"""The CPU march's chunks of a batch (swim.rt.march.chunk_spans): factoring, so that all cores finish together."""

import numpy as np
import pytest

from swim.rt.march import chunk_spans


@pytest.mark.parametrize("n", [1, 2, 3, 7, 255, 1681, 4096, 10_000, 80_000, 823_593])
@pytest.mark.parametrize("chunk, cores", [(4096, 1), (4096, 2), (4096, 16), (1000, 3), (1, 2)])
def test_the_chunks_cover_the_batch_in_order_and_shrink_towards_its_end(n, chunk, cores):
    spans = chunk_spans(n, chunk, cores, least=512)
    sizes = np.array([hi - lo for lo, hi in spans])
    assert spans[0][0] == 0 and spans[-1][1] == n
    assert all(a[1] == b[0] for a, b in zip(spans, spans[1:])), "consecutive, no ray twice or left out"
    assert sizes.min() >= 1 and sizes.max() <= chunk
    assert np.all(np.diff(sizes) <= 1), "no chunk bigger than the one before it (by more than a ray's rounding)"
    last = sizes[-min(cores, sizes.size):]
    assert last.max() - last.min() <= 1, "the last round splits what is left evenly"
    if n >= cores:
        assert sizes.size >= cores, "a small batch still runs on every core"


def test_a_big_batch_ends_in_chunks_much_smaller_than_its_first():
    sizes = [hi - lo for lo, hi in chunk_spans(80_000, 4096, 2, least=512)]
    assert sizes[0] == 4096
    assert max(sizes[-2:]) < 4096 / 4, "the cores' last chunks take a fraction of a full one"
    assert len(sizes) <= 80_000 // 4096 + 2 * 2 * 4, "a few more chunks than equal ones, not many"


def test_every_chunk_but_the_last_rounds_has_at_least_least_rays():
    least = 512
    spans = chunk_spans(300_000, 4096, 2, least=least)
    sizes = np.array([hi - lo for lo, hi in spans])
    assert np.all(sizes[:-2] >= least) and np.all(sizes[-2:] < 2 * least)


def test_a_batch_smaller_than_two_rounds_of_least_is_split_evenly_once():
    assert chunk_spans(1681, 4096, 2, least=512) == [(0, 841), (841, 1681)]
    assert chunk_spans(5, 4096, 2, least=512) == [(0, 3), (3, 5)]
    assert chunk_spans(0, 4096, 2) == []
