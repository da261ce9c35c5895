"""extract runs its frames with OpenCV on one thread (stages.common.resources'
opencv_single_threaded) and gives the process its thread pool back afterwards, also when
blocks overlap in threads of one process."""

from __future__ import annotations

import threading

import cv2
import pytest

from stages import extract, simulate
from stages.common import resources
from stages.common.resources import opencv_single_threaded


@pytest.fixture
def two_threads():
    before = cv2.getNumThreads()
    cv2.setNumThreads(2)
    yield
    cv2.setNumThreads(before)


def test_extract_uses_one_thread_and_restores_the_pool(tmp_path, two_threads, monkeypatch):
    """While extract.main works on its frames OpenCV has one thread; after it, the two it had."""
    data = simulate.main(dict(simulate.confs["perspective-default"], frames=2, seed=11),
                         "kidsize", tmp_path / "kid")
    seen = []
    read = extract.read_frame

    def reading(path):
        seen.append(cv2.getNumThreads())
        return read(path)

    monkeypatch.setattr(extract, "read_frame", reading)
    extract.main(None, data, tmp_path / "f.h5")
    assert seen == [1, 1]
    assert cv2.getNumThreads() == 2


def test_overlapping_blocks_restore_the_pool_when_the_last_ends(two_threads):
    """Blocks of two threads overlapping in any order: one thread while any runs, the pool's
    two again once both have ended."""
    first_in, second_done = threading.Event(), threading.Event()
    inside = []

    def first():
        with opencv_single_threaded():
            first_in.set()
            second_done.wait(10)
            inside.append(cv2.getNumThreads())

    t = threading.Thread(target=first)
    t.start()
    first_in.wait(10)
    with opencv_single_threaded():
        inside.append(cv2.getNumThreads())
    second_done.set()
    inside.append(cv2.getNumThreads())  # the first block still runs
    t.join(10)
    assert inside[:2] == [1, 1] and inside[2] in (1, 2)
    assert cv2.getNumThreads() == 2 and resources._opencv_blocks == 0
