"""bench opcua --pin: threads are pinned one by one and checked, the rig's CPU load is read per CPU, pairs give
their own extra, the burner takes the share asked for, and the command line says what was run."""

from __future__ import annotations

import os
import threading
import time
from collections import namedtuple

import pytest

from bench import opcua, pinning

Times = namedtuple("Times", "user nice system idle iowait irq softirq steal")

needs_two_cpus = pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2 or not hasattr(os, "sched_setaffinity"),
                                    reason="pinning needs two CPUs this process may use")


def test_busy_share_leaves_out_idle_iowait_and_steal() -> None:
    before = [Times(0, 0, 0, 0, 0, 0, 0, 0), Times(10, 0, 0, 10, 0, 0, 0, 0)]
    after = [Times(3, 0, 1, 4, 1, 0, 1, 0), Times(10, 0, 0, 14, 0, 0, 0, 6)]
    assert pinning.cpu_busy_pct(before, after) == pytest.approx([50.0, 0.0])


def test_a_cpu_that_did_not_tick_is_not_busy() -> None:
    same = [Times(1, 0, 0, 1, 0, 0, 0, 0)]
    assert pinning.cpu_busy_pct(same, same) == [0.0]


def test_pairs_compare_run_by_run() -> None:
    assert pinning.paired_extra_pct([100.0, 200.0], [130.0, 190.0]) == pytest.approx([30.0, -5.0])
    assert pinning.paired_extra_pct([0.0, 100.0], [50.0, 110.0]) == pytest.approx([10.0])


@pytest.mark.parametrize(("cores", "busy", "asleep"), [(0.25, 0.005, 0.015), (1.5, 0.02, 0.0), (-1, 0.0, 0.02)])
def test_duty_is_clamped_to_one_cpu(cores: float, busy: float, asleep: float) -> None:
    assert pinning.duty_slices(cores) == pytest.approx((busy, asleep))


@needs_two_cpus
def test_pin_reaches_threads_started_before_it_and_after_it() -> None:
    """Affinity is per thread: a thread already running must be pinned by its own id, a later one inherits."""
    own = frozenset(os.sched_getaffinity(0))
    stop = threading.Event()
    early = threading.Thread(target=stop.wait)
    early.start()
    try:
        assert pinning.pin(os.getpid(), pinning.RIG_CPUS) >= 2
        late = threading.Thread(target=stop.wait)
        late.start()
        assert pinning.affinities(os.getpid()) == {pinning.RIG_CPUS}
        assert pinning.check_pinned({"me": os.getpid()}, pinning.RIG_CPUS) == []
        assert pinning.check_pinned({"me": os.getpid()}, pinning.DAEMON_CPUS) == ["me"]
    finally:
        stop.set()
        early.join()
        if "late" in locals():
            late.join()
        pinning.pin(os.getpid(), own)
    assert pinning.affinities(os.getpid()) == {own}


def test_a_process_gone_is_neither_pinned_nor_a_stray() -> None:
    gone = 2**22 + 7  # above the default pid_max
    assert pinning.pin(gone, pinning.RIG_CPUS) == 0
    assert pinning.check_pinned({"gone": gone}, pinning.RIG_CPUS) == []


@needs_two_cpus
def test_burner_inherits_the_affinity_and_burns() -> None:
    """The burner runs where the bench process was pinned, and it burns CPU (how much of its share it gets
    depends on the host's load: that is the bench's to report, not a test's to time)."""
    import psutil

    own = frozenset(os.sched_getaffinity(0))
    pinning.pin(os.getpid(), pinning.RIG_CPUS)
    try:
        burner = pinning.Burner(0.5)
    finally:
        pinning.pin(os.getpid(), own)
    try:
        process = psutil.Process(burner.proc.pid)
        deadline = time.monotonic() + 20
        while process.cpu_times().user < 0.2 and time.monotonic() < deadline:  # past the interpreter's start
            time.sleep(0.05)
        assert pinning.affinities(burner.proc.pid) == {pinning.RIG_CPUS}
        first = process.cpu_times().user
        while process.cpu_times().user < first + 0.1 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert process.cpu_times().user >= first + 0.1
    finally:
        burner.stop()
    assert burner.proc.returncode is not None


def test_command_line_names_pin_burn_and_no_burst_only_when_asked() -> None:
    plain = opcua.command_line(False, 100, 20.0, 2, opcua.MODES, False)
    assert plain == "python -m bench opcua --sizes 100 --duration 20 --repeat 2"
    asked = opcua.command_line(False, 100, 20.0, 3, ("off", "burn"), False, pin=True, burn_cores=0.15,
                               with_burst=False)
    assert asked == "python -m bench opcua --sizes 100 --duration 20 --repeat 3 --modes off,burn --pin " \
                    "--burn-cores 0.15 --no-burst"


def test_burn_serves_no_client() -> None:
    assert opcua.opcua_section("burn", 7, opcua.Path("/p")) == ""
    assert "burn" in opcua.CLIENTLESS and "burn" in opcua.ALL_MODES
