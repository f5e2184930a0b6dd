"""A threaded source whose 'device' is a queue the test fills (and can break)."""

import queue

from fovjax.devices import ThreadedSource


class Disconnect(Exception):
    pass


class FeedSource(ThreadedSource):
    kind = "gaze"

    def __init__(self, **kwargs):
        super().__init__(backoff_initial=0.01, backoff_max=0.02, **kwargs)
        self.device: queue.Queue = queue.Queue()

    def _connect(self):
        pass

    def _read_some(self):
        out = []
        try:
            item = self.device.get(timeout=0.02)
        except queue.Empty:
            return out
        while True:
            if item is Disconnect:
                raise Disconnect("the fake device went away")
            out.append(item)
            try:
                item = self.device.get_nowait()
            except queue.Empty:
                return out

    def _disconnect(self):
        pass
