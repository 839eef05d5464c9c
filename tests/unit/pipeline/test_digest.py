"""swim.digest: digests of arrays for the in-process caches."""

import numpy as np
import pytest
import xxhash

import swim.digest as digest


@pytest.mark.parametrize("shape", [(), (7,), (5, 6), (4, 3, 9)])
def test_an_array_hashes_by_its_values_in_c_order_whatever_its_layout(shape, monkeypatch):
    monkeypatch.setattr(digest, "BLOCK_BYTES", 16)  # a non-contiguous array is fed in many blocks of rows
    values = np.random.default_rng(1).random(shape)
    reference = xxhash.xxh3_128(np.ascontiguousarray(values).tobytes()).digest()
    for layout in (values, np.asfortranarray(values), values.T.copy().T):
        h = xxhash.xxh3_128()
        digest.update_with_array(h, layout)
        assert h.digest() == reference
    if values.size:
        changed = np.asfortranarray(values)
        changed.reshape(-1, order="A")[-1] += 1e-9
        h = xxhash.xxh3_128()
        digest.update_with_array(h, changed)
        assert h.digest() != reference


def test_array_digest_sees_dtype_and_shape():
    a = np.arange(12, dtype=np.float64)
    assert digest.array_digest(a) == digest.array_digest(a.copy())
    assert digest.array_digest(a) != digest.array_digest(a.reshape(3, 4))  # same bytes, another shape
    assert digest.array_digest(a) != digest.array_digest(a.view(np.int64))  # same bytes, another dtype
    assert len(digest.array_digest(a)) == 16
