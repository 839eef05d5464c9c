"""Digests of arrays for swim's in-process caches: streaming XXH3-128 (``xxhash``).

XXH3 hashes ~34 GB/s on one core here, SHA-256 1.8 GB/s (docs/decisions/0009-work-around-the-march.md). The digests key
caches within one process (the stage cache's scene digest, the crop's column geometry); they are not meant to resist
crafted collisions.
"""

from __future__ import annotations

import numpy as np
import xxhash

#: Bytes per block in which a non-contiguous array is copied to be hashed (bounds the copy).
BLOCK_BYTES = 1 << 24


def update_with_array(digest, values) -> None:
    """Feed an array's values, in C order, to a streaming digest (e.g. ``xxhash.xxh3_128()``).

    A C-contiguous array is hashed in place; any other is copied and hashed in blocks of rows of at most
    :data:`BLOCK_BYTES` bytes, never whole (a streaming digest does not depend on how its input is cut, so both
    give the same digest). The dtype and shape are not hashed: callers add them where they matter.
    """
    values = np.asarray(values)
    if values.flags.c_contiguous:
        digest.update(values.reshape(-1).view(np.uint8).data)
        return
    rows = max(1, BLOCK_BYTES // max(values[0].nbytes, 1))
    for lo in range(0, values.shape[0], rows):
        digest.update(np.ascontiguousarray(values[lo:lo + rows]).reshape(-1).view(np.uint8).data)


def array_digest(values) -> bytes:
    """XXH3-128 digest (16 bytes) of an array's dtype, shape and values."""
    values = np.asarray(values)
    digest = xxhash.xxh3_128(f"{values.dtype}{values.shape}".encode())
    update_with_array(digest, values)
    return digest.digest()
