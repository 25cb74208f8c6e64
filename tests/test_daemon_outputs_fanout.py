"""The outputs' own thread (``outputs/fanout.py``): items in order, the oldest prediction
dropped when the outputs fall behind (never a status), a bad item never ends the
thread, and a stop that does not wait forever for outputs that hang."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest
from scotti.daemon.frames.pipeline import Prediction
from scotti.daemon.mqtt import messages
from scotti.daemon.outputs.fanout import FRAMES_PER_DEVICE, Item, OutputThread

from tests.support.outputs import predictions
from tests.support.sessions import write_synthetic_session

WAIT_S = 10.0


@pytest.fixture(scope="module")
def preds(tmp_path_factory: pytest.TempPathFactory, tiny_model_path: Path) -> list[Prediction]:
    session = write_synthetic_session(tmp_path_factory.mktemp("fanout") / "s.scotti", frames=48)
    out = predictions(session.path, tiny_model_path)
    assert len(out) >= 3
    return out


class Recorder:
    """A ``handle`` that writes down what it got; it can be held up (``gate``)."""

    def __init__(self) -> None:
        self.got: list[Item] = []
        self.gate = threading.Event()
        self.gate.set()
        self.holding = threading.Event()  # set while an item waits at the gate

    def __call__(self, item: Item) -> None:
        if not self.gate.is_set():
            self.holding.set()
            self.gate.wait(WAIT_S)
        self.got.append(item)


def test_a_full_queue_drops_the_oldest_predictions_never_a_status(
    preds: list[Prediction],
) -> None:
    handle = Recorder()
    handle.gate.clear()
    thread = OutputThread(handle, devices=1)
    first = Item("a", prediction=preds[0])
    thread.submit(first)  # taken at once, held at the gate: the queue behind it fills
    assert handle.holding.wait(WAIT_S)
    online = Item("a", status=messages.status("online", [], None))
    thread.submit(online)
    extra = 5
    queued = [Item("a", prediction=preds[k % len(preds)]) for k in range(FRAMES_PER_DEVICE + extra)]
    for item in queued:
        thread.submit(item)
    handle.gate.set()
    assert thread.close(WAIT_S)
    assert thread.dropped == extra + 1  # the queue holds FRAMES_PER_DEVICE, the status one
    assert thread.dropped_of("a") == extra + 1
    assert handle.got[:2] == [first, online]
    assert handle.got[2:] == queued[extra + 1 :]  # the newest, in order


def test_a_dropped_prediction_is_counted_for_its_own_device(preds: list[Prediction]) -> None:
    # Each device's health reports its own drops: one device's backlog makes room for
    # another's newer frames, and the drop is the backlogged device's.
    handle = Recorder()
    handle.gate.clear()
    thread = OutputThread(handle, devices=2)  # room for 2 * FRAMES_PER_DEVICE
    thread.submit(Item("a", prediction=preds[0]))  # taken at once, held at the gate
    assert handle.holding.wait(WAIT_S)
    for k in range(FRAMES_PER_DEVICE):
        thread.submit(Item("a", prediction=preds[k % len(preds)]))
    extra = 3
    for k in range(FRAMES_PER_DEVICE + extra):
        thread.submit(Item("b", prediction=preds[k % len(preds)]))
    handle.gate.set()
    assert thread.close(WAIT_S)
    assert (thread.dropped_of("a"), thread.dropped_of("b")) == (extra, 0)
    assert thread.dropped_of("c") == 0  # a device that never handed anything over
    assert thread.dropped == extra


def test_a_failing_item_does_not_end_the_thread(
    preds: list[Prediction], caplog: pytest.LogCaptureFixture
) -> None:
    got: list[Item] = []

    def handle(item: Item) -> None:
        if item.status is not None:
            msg = "an output's bug"
            raise ValueError(msg)
        got.append(item)

    thread = OutputThread(handle, devices=2)
    for _ in range(2):
        thread.submit(Item("a", status=messages.status("online", [], None)))
    after = [Item("b", prediction=p) for p in preds[:3]]
    for item in after:
        thread.submit(item)
    assert thread.close(WAIT_S)
    assert got == after
    assert thread.failed == 2
    warned = [r for r in caplog.records if "an item failed" in r.getMessage()]
    assert len(warned) == 1  # logged once, counted from then on


def test_close_gives_up_on_outputs_that_hang(preds: list[Prediction]) -> None:
    handle = Recorder()
    handle.gate.clear()
    thread = OutputThread(handle, devices=1)
    for p in preds[:3]:
        thread.submit(Item("a", prediction=p))
    assert handle.holding.wait(WAIT_S)
    assert not thread.close(0.2)
    assert thread.abandoned == 2  # the two behind the one in hand
    handle.gate.set()  # the item in hand finishes; the rest never go out
    thread._thread.join(WAIT_S)
    assert not thread._thread.is_alive()
    assert [i.prediction for i in handle.got] == [preds[0]]
    thread.submit(Item("a", prediction=preds[0]))  # after close: ignored
    assert len(handle.got) == 1
