"""Tests for the quick-mode flag."""

import pytest

from wbmpc.quick import QUICK_ENV, pick, quick_mode


@pytest.mark.parametrize("value", ["1", "true", "TRUE", "True", "yes", "YES", " yes "])
def test_quick_mode_on(monkeypatch, value):
    monkeypatch.setenv(QUICK_ENV, value)
    assert quick_mode() is True
    assert pick(full=100, quick=3) == 3


@pytest.mark.parametrize("value", ["", "0", "false", "no", "off", "2"])
def test_quick_mode_off(monkeypatch, value):
    monkeypatch.setenv(QUICK_ENV, value)
    assert quick_mode() is False
    assert pick(full=100, quick=3) == 100


def test_quick_mode_unset(monkeypatch):
    monkeypatch.delenv(QUICK_ENV, raising=False)
    assert quick_mode() is False
    assert pick(full="full", quick="quick") == "full"


def test_pick_keyword_and_positional(monkeypatch):
    monkeypatch.setenv(QUICK_ENV, "1")
    assert pick(10, 2) == 2
    assert pick(full=[1, 2, 3], quick=[1]) == [1]
    monkeypatch.setenv(QUICK_ENV, "0")
    assert pick(10, 2) == 10


def test_env_name():
    assert QUICK_ENV == "WBMPC_QUICK"


def test_package_exports():
    import wbmpc

    assert wbmpc.pick is pick
    assert wbmpc.quick_mode is quick_mode
    assert wbmpc.__version__ == "0.1.0"
