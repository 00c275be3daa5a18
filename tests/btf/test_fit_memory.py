"""The fitter's extra memory does not grow with frame size."""
import tracemalloc

import numpy as np

from btf.fit.fitter import FrameFitter


def peak_extra(side: int) -> int:
    frame = np.zeros((side, side, 3), dtype=np.uint8)
    frame[::3] = 200
    labels = np.zeros((side, side), dtype=np.int32)
    labels[side // 2:] = 1
    fitter = FrameFitter(n_labels=2, n_bands=3, chunk_rows=16)
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        fitter.add(frame, labels)
        fitter.fit()
        return tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def test_peak_memory_is_the_same_for_small_and_large_frames():
    small, large = peak_extra(500), peak_extra(2000)
    # one chunk: chunk_rows * 1024 pixels * 3 bands of intp indices
    chunk_bytes = 16 * 1024 * 3 * np.dtype(np.intp).itemsize
    assert abs(large - small) <= chunk_bytes
    assert large < 3 * chunk_bytes + 64 * 1024  # bounded by the chunk, not by the 12 MB frame
