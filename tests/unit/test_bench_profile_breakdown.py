"""bench.profile_breakdown charges each profiled sample to the daemon's layer that spent it (no timings)."""

from __future__ import annotations

from bench import profile_breakdown

ROOT = ["MainThread\x00<thread>\x001", "run_daemon\x00/repo/edge/service/daemon.py\x0010\x01l20",
        "_run_once\x00/py/lib/python3.11/asyncio/base_events.py\x001\x01l2",
        "_run\x00/py/lib/python3.11/asyncio/events.py\x001\x01l2"]


def frame(function: str, path: str, line: int = 1) -> str:
    return f"{function}\x00{path}\x001\x01l{line}"


def test_each_sample_goes_to_the_first_daemon_frame_from_its_leaf_and_idle_is_left_out() -> None:
    tick = frame("_tick", "/repo/edge/collect/poller.py", 400)
    session = {"frame_records": [
        # a C call made by the client's batch: the client's
        [[*ROOT, tick, frame("_batch", "/repo/edge/focas/client.py"), "len\x00<built-in>\x000"], 3.0],
        # the request's write, through asyncio's transport, to the socket: the floor's own I/O
        [[*ROOT, tick, frame("send", "/repo/edge/focas/client.py"),
          frame("write", "/py/lib/python3.11/asyncio/selector_events.py"), "socket.send\x00<built-in>\x000"], 2.0],
        # a Sample built in report's last lines
        [[*ROOT, tick, frame("report", "/repo/edge/collect/changes.py", 70)], 1.0],
        # the loop's own bookkeeping, and waiting in epoll (idle)
        [[*ROOT[:3], "time\x00/py/lib/python3.11/asyncio/base_events.py\x001\x01l5"], 0.5],
        [[*ROOT[:3], "epoll.poll\x00<built-in>\x000"], 10.0],
    ]}
    busy, layers = profile_breakdown.breakdown(session)
    assert busy == 6.5
    assert layers == {
        "FOCAS client (prepared request, answer split, decode of what moved)": 3.0,
        profile_breakdown.SOCKET_IO: 2.0,
        "Sample building (in report)": 1.0,
        profile_breakdown.LOOP: 0.5,
    }
