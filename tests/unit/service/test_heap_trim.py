"""heap_trim: glibc's malloc_trim where there is one, nothing (and no error) where there is not."""

from __future__ import annotations

import ctypes

import pytest

from edge.service import heap_trim


def test_trim_answers_without_raising() -> None:
    assert heap_trim.trim() in (True, False)


def test_without_malloc_trim_it_does_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    class NoTrim:  # a C library without malloc_trim (musl, macOS)
        def __init__(self, name: object) -> None:
            pass

    heap_trim._malloc_trim.cache_clear()
    monkeypatch.setattr(ctypes, "CDLL", NoTrim)
    try:
        assert heap_trim.trim() is False
    finally:
        heap_trim._malloc_trim.cache_clear()
