"""What the launcher learns from a dead worker (``service/supervision.py``): the cause of its
end, the stream it was working on (read from shared memory after a real process died with
it), and the strikes that quarantine a stream."""

from __future__ import annotations

import multiprocessing as mp
import os
import signal

import pytest

from arcf.service.settings import ServiceSettings
from arcf.service.supervision import MARK_BYTES, InFlight, Strikes, death_cause


@pytest.mark.parametrize(("exitcode", "cause"), [
    (-signal.SIGSEGV, "SIGSEGV"), (-signal.SIGKILL, "SIGKILL"), (-signal.SIGABRT, "SIGABRT"),
    (1, "exit 1"), (0, "exit 0"), (None, "unknown"), (-200, "signal 200")])
def test_a_death_is_named_by_its_signal_or_exit_code(exitcode: int | None, cause: str) -> None:
    assert death_cause(exitcode) == cause


def _die_on(mark: InFlight, stream: str) -> None:
    mark.set(stream)
    os.kill(os.getpid(), signal.SIGSEGV)


def _finish(mark: InFlight, stream: str) -> None:
    mark.set(stream)
    mark.clear()


def test_the_mark_of_a_process_that_died_mid_frame_is_read_after_it() -> None:
    ctx = mp.get_context("spawn")
    mark = InFlight(ctx)
    proc = ctx.Process(target=_die_on, args=(mark, "cam-7"))
    proc.start()
    proc.join(timeout=60)
    assert death_cause(proc.exitcode) == "SIGSEGV"
    assert mark.read() == "cam-7"
    mark.clear()
    done = ctx.Process(target=_finish, args=(mark, "cam-8"))
    done.start()
    done.join(timeout=60)
    assert done.exitcode == 0 and mark.read() is None  # between frames: nobody to blame


def test_a_long_id_is_cut_not_overflowed() -> None:
    mark = InFlight(mp.get_context("spawn"))
    mark.set("x" * 500)
    assert mark.read() == "x" * (MARK_BYTES - 1)
    mark.set("short")  # a shorter id after a long one reads alone
    assert mark.read() == "short"


class _Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_strikes_quarantine_within_the_window_and_the_quarantine_ends() -> None:
    clock = _Clock()
    strikes = Strikes(quarantine_after=2, quarantine_s=600, clock=clock)
    assert not strikes.strike("a")
    clock.now += 601  # the first strike has aged out
    assert not strikes.strike("a") and strikes.count("a") == 1
    assert not strikes.strike("b")  # another stream's strike is its own
    assert strikes.quarantined("a") == 0
    clock.now += 10
    assert strikes.strike("a")
    assert strikes.quarantined("a") == pytest.approx(600)
    assert strikes.quarantined("b") == 0
    clock.now += 599
    assert strikes.quarantined("a") == pytest.approx(1)
    clock.now += 2
    assert strikes.quarantined("a") == 0 and strikes.count("a") == 0


def test_zero_strikes_never_quarantine() -> None:
    strikes = Strikes(quarantine_after=0, quarantine_s=600)
    assert not any(strikes.strike("a") for _ in range(5))
    assert strikes.quarantined("a") == 0


def test_the_settings_refuse_a_quarantine_without_a_window() -> None:
    with pytest.raises(ValueError, match="quarantine"):
        ServiceSettings(quarantine_s=0)
    with pytest.raises(ValueError, match="quarantine"):
        ServiceSettings(quarantine_after=-1)
