"""Encoding an episode's view while its frames are still being decoded.

Frame sources that decode (LeRobot videos, RLBench image files) offer ``iter_load(indices, chunk)``;
a small thread runs it a couple of chunks ahead while the encoder works on the current one (PyAV,
PIL and ONNX Runtime release the GIL while they work). Other sources are loaded whole, as before.
"""

from __future__ import annotations

import contextlib
import queue
import threading
from collections.abc import Iterator, Sequence

import numpy as np

from rdd.data.episode import Episode
from rdd.encoders.base import Encoder

PREFETCH = 2  # chunks decoded ahead: enough to hide decoding, little memory (2 x 32 frames)
_END = object()


def _put(q: queue.Queue, item: object, stop: threading.Event) -> bool:
    """Put ``item`` unless ``stop`` is set first (checked while the queue is full); True when put."""
    while not stop.is_set():
        try:
            q.put(item, timeout=0.1)
            return True
        except queue.Full:
            continue
    return False


def prefetch(chunks: Iterator[np.ndarray], depth: int = PREFETCH) -> Iterator[np.ndarray]:
    """The items of ``chunks``, produced by a background thread up to ``depth`` items ahead.

    An exception in the producer is raised here; leaving the loop early stops the producer.
    """
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def produce() -> None:
        last: object = _END
        try:
            for item in chunks:
                if not _put(q, item, stop):
                    break
            close = getattr(chunks, "close", None)
            if close is not None:
                close()  # a generator's `with` blocks (open video files) end here, in this thread
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer
            last = exc
        _put(q, last, stop)  # always: the consumer waits for it

    worker = threading.Thread(target=produce, name="rdd-frame-prefetch", daemon=True)
    worker.start()
    try:
        while True:
            item = q.get()
            if item is _END:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        worker.join()


def encode_view(encoder: Encoder, episode: Episode, view: str,
                indices: Sequence[int] | np.ndarray | None = None) -> np.ndarray:
    """``encoder.encode(episode.frames(view, indices))``, with decoding overlapped with encoding."""
    source = episode.views.get(view)
    iter_load = getattr(source, "iter_load", None)
    if iter_load is None:  # in memory, or a source that loads whole (and the unknown-view error)
        return encoder.encode(episode.frames(view, indices))
    chunk = max(1, int(getattr(encoder, "batch_size", 32)))
    with contextlib.closing(prefetch(iter_load(indices, chunk))) as chunks:
        outs = [encoder.encode(frames) for frames in chunks]
    if not outs:
        return np.zeros((0, int(encoder.dim)), dtype=np.float32)
    return np.concatenate(outs, axis=0)
