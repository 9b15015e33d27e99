"""pybullet, imported once without its build-time banner, with the install line when it is missing."""

from __future__ import annotations

from envs.quiet import native_output_silenced

try:
    with native_output_silenced():  # pybullet prints its build-time banner on import
        import pybullet as pb
        import pybullet_data
        from pybullet_utils import bullet_client
except ImportError as exc:  # pragma: no cover - depends on the install
    raise ImportError(
        "the envs package needs pybullet: make install (or pip install -c constraints.txt -e '.[sim]')"
    ) from exc

__all__ = ["bullet_client", "pb", "pybullet_data"]
