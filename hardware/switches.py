"""factr2's environment switches, read in one place. Each call reads the environment as it is now (a test or
a parent process sets them before a call), and nothing else in the tree reads a FACTR2_* variable
(tests/test_architecture.py).

- FACTR2_NO_RT: no SCHED_FIFO, no CPU pinning, no CPU wake-up latency request (A/B timing; realtime.py)
- FACTR2_NO_PIN: no CPU pinning only (realtime.LoopCpu)
- FACTR2_CACHE: factr2's folder for caches (default ~/.cache/factr2): the NEXT cache, leader gravity
- FACTR2_RECORDING_CACHE: recordings' derived caches (default FACTR2_CACHE/recordings; recording/cache.py)
- FACTR2_ARMS: the user's arm folder, where `factr2 arm import` writes (default $XDG_CONFIG_HOME/factr2/arms,
  ~/.config/factr2/arms; hardware/arms)

The render process's address (FACTR2_RENDER_ADDR, _KEY) is a parent-to-child handshake, not a switch.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Switches:
    no_rt: bool
    no_pin: bool
    cache: Path
    recording_cache: Path
    arms: Path


def switches() -> Switches:
    """The FACTR2_* switches as the environment has them now (a set switch is any non-empty value)."""
    cache = Path(os.environ.get("FACTR2_CACHE") or Path.home() / ".cache" / "factr2")
    config = Path(os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config")
    return Switches(no_rt=bool(os.environ.get("FACTR2_NO_RT")), no_pin=bool(os.environ.get("FACTR2_NO_PIN")),
                    cache=cache,
                    recording_cache=Path(os.environ.get("FACTR2_RECORDING_CACHE") or cache / "recordings"),
                    arms=Path(os.environ.get("FACTR2_ARMS") or config / "factr2" / "arms").expanduser())
