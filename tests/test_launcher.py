import sys

import pytest

from bop_cender import launcher


@pytest.fixture
def calls(monkeypatch):
    seen = []
    monkeypatch.setattr(launcher.os, "execve", lambda exe, args, env: seen.append((exe, args, env)))
    monkeypatch.setattr(launcher, "find_tcmalloc", lambda: "/usr/lib/x/libtcmalloc_minimal.so.4")
    for key in ("LD_PRELOAD", launcher.ALLOCATOR_ENV, launcher._REEXEC_ENV):
        monkeypatch.delenv(key, raising=False)
    return seen


def test_reexec_preloads_tcmalloc_once(calls):
    launcher.reexec_with_tcmalloc(["synth", "--layout", "dimo"])
    ((exe, args, env),) = calls
    assert exe == sys.executable and args[1:] == ["-m", "bop_cender.cli", "synth", "--layout", "dimo"]
    assert env["LD_PRELOAD"].startswith("/usr/lib/x/libtcmalloc_minimal.so.4")
    assert env[launcher._REEXEC_ENV] == "1"


@pytest.mark.parametrize(
    "env", [{"BOP_CENDER_ALLOCATOR": "system"}, {"LD_PRELOAD": "/lib/libtcmalloc.so"}, {"BOP_CENDER_REEXEC": "1"}]
)
def test_no_reexec_when_disabled_active_or_already_done(calls, monkeypatch, env):
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    launcher.reexec_with_tcmalloc(["synth"])
    assert calls == []


def test_no_reexec_without_the_library(calls, monkeypatch):
    monkeypatch.setattr(launcher, "find_tcmalloc", lambda: None)
    launcher.reexec_with_tcmalloc(["synth"])
    assert calls == []
