"""Workspaces: the scenes views come from.

A workspace source plugin (:class:`~ssga_core.stages.WorkspaceSource`) opens a
:class:`Workspace`; the benchmark protocol (cells, classes, view overlap) is applied to
it by the core, whatever the source.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from ssga_core.data import View
from ssga_core.geometry import Camera, Pose


@runtime_checkable
class Workspace(Protocol):
    """A scene that can show what a camera at any pose sees."""

    name: str
    camera: Camera

    def render(self, pose: Pose) -> View:
        """The view from ``pose``."""
        ...
