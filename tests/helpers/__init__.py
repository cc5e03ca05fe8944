"""Helpers shared by test modules of several rooms (a test module never imports another test module).

``REPO`` is the checkout's root; ``netns`` the network-namespace processes, ``fuzz`` the exit-code check of
the fuzz tests, ``service`` the daemon's config and pipeline on a test bus.
"""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
