"""Hypothesis profiles: "default" sized for CI, "stress" for `make stress` (--hypothesis-profile=stress);
the `fake_robot` fixture every runtime test builds its robot with; `host` runs `btf-host` in-process."""
from __future__ import annotations

import pytest
from hypothesis import HealthCheck, settings

from tools import cli

settings.register_profile("default", max_examples=100, deadline=None)
settings.register_profile("stress", max_examples=5000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
settings.load_profile("default")


@pytest.fixture
def fake_robot(tmp_path):
    """Builds robot runtimes on the fake HAL over the in-memory link:
    `fake_robot(config_text, where=tmp_path, transport=None, hal=None, quota=None, **runtime_kw)`
    writes `where/robot.toml`, builds its HAL (camera opened at `hal.size`) unless one is given,
    and returns (Runtime, MemoryTransport). `quota`: an outbox of that many bytes. The same
    `where` again is a restart on the same state."""
    from hal.factory import build_hal
    from onboard import config
    from onboard.capture.segmentation import Segmentation
    from onboard.link.outbox import Outbox
    from onboard.link.transport import MemoryTransport
    from onboard.runtime import Runtime

    def make(text, where=None, transport=None, hal=None, quota=None, **runtime_kw):
        where = tmp_path if where is None else where
        where.mkdir(parents=True, exist_ok=True)
        (where / "robot.toml").write_text(text)
        cfg = config.load(where / "robot.toml")
        if hal is None:
            hal = build_hal(cfg.hal)
            hal.open_camera()
        if quota is not None:
            cfg.state_dir.mkdir(parents=True, exist_ok=True)
            runtime_kw["outbox"] = Outbox(cfg.state_dir / "outbox.sqlite", quota_bytes=quota)
        tr = MemoryTransport() if transport is None else transport
        return Runtime(cfg, hal, tr, Segmentation(cfg, hal), **runtime_kw), tr

    return make


@pytest.fixture
def host(capsys):
    """`host(*argv)` runs `btf-host` in this process: (exit status, stdout, stderr)."""
    def run(*argv):
        code = cli.main([str(a) for a in argv])
        out, err = capsys.readouterr()
        return code, out, err
    return run
