"""depthguard.buffers: large per-set arrays passed from one owner to the next, and dropped so that their pages go
back to the operating system."""

from __future__ import annotations

import gc

import numpy as np

from depthguard import buffers


class Owner:
    """Anything that supports weak references."""


def test_an_array_passes_to_the_next_owner_once_the_first_is_collected():
    first = Owner()
    a = buffers.reusable((7, 5, 3), np.uint8, first, new=np.zeros)
    assert a.shape == (7, 5, 3) and a.dtype == np.uint8 and not a.any()
    a[1, 2, 0] = 9
    held = Owner()
    b = buffers.reusable((7, 5, 3), np.uint8, held)  # the first still holds its array: a new one
    assert b is not a
    del first
    gc.collect()
    again = Owner()
    c = buffers.reusable((7, 5, 3), np.uint8, again)
    assert c is a and c[1, 2, 0] == 9  # what its last owner left
    other = Owner()
    assert buffers.reusable((7, 5, 3), np.float32, other) is not a  # another kind is another array


def test_dropped_arrays_are_not_handed_out_again_not_even_those_in_use():
    shape = (4, 6, 2)
    owners = [Owner(), Owner()]
    in_use, spare = (buffers.reusable(shape, np.uint8, owner) for owner in owners)
    del owners[1]
    gc.collect()  # the second array is a spare now, the first still in use
    buffers.drop_spares(shape, np.uint8)
    del owners[0]
    gc.collect()  # the first comes back after the drop: not kept
    later = [Owner() for _ in range(3)]
    handed = [buffers.reusable(shape, np.uint8, owner) for owner in later]
    assert all(h is not in_use and h is not spare for h in handed)
    del later[0]
    gc.collect()
    assert buffers.reusable(shape, np.uint8, Owner()) is handed[0]  # arrays made after the drop are reused again
