"""The 3-D scene's pieces: polylines redrawn in place, and the MuJoCo arm of a scene as viser meshes."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from . import scene3d

MAX_LINE_POINTS = 200
"""Polylines sent to the 3-D scene are resampled to this many points."""


def polyline(points: np.ndarray, n: int = MAX_LINE_POINTS) -> np.ndarray:
    """``(N, 3)`` points → ``(n - 1, 2, 3)`` segments for ``add_line_segments``, resampled to ``n`` points: always
    the same count, so a redraw updates the line's points in place (no new scene node for the browser to build)."""
    s = np.linspace(0, len(points) - 1, n)
    p = np.stack([np.interp(s, np.arange(len(points)), points[:, i]) for i in range(3)], axis=1)
    return np.stack([p[:-1], p[1:]], axis=1).astype(np.float32)


class SceneLine:
    """A polyline in the 3-D scene whose points are replaced in place on every redraw."""

    def __init__(self, server: Any, name: str, rgb: tuple[int, int, int], thickness: float) -> None:
        self.server, self.name, self.rgb, self.thickness = server, name, rgb, thickness
        self.handle: Any = None

    def set(self, points: np.ndarray, visible: bool = True) -> None:
        if not visible:  # the page's "paths in 3D" is off: leave the scene alone (no 3-D redraw)
            if self.handle is not None and self.handle.visible:
                self.handle.visible = False
            return
        segments = polyline(points)
        if self.handle is not None and not self.handle.visible:
            self.handle.visible = True
        if self.handle is None:
            self.handle = self.server.scene.add_line_segments(self.name, segments, self.rgb, thickness=self.thickness,
                                                              thickness_units="screen")
        else:
            self.handle.points = segments


def about_x(theta: float) -> tuple[float, float, float, float]:
    return (math.cos(theta / 2), math.sin(theta / 2), 0.0, 0.0)


class ArmView:
    """The MuJoCo arm of one scene in viser: a frame per body, the body's geoms as meshes under it; replays
    move the frames. ``robot``: a standard arm's name (its link meshes, simplified to
    :data:`.scene3d.MESH_FACE_BUDGET` triangles), ``None`` the built-in arm."""

    def __init__(self, server: Any, root: str, kind: str, robot: str | None = None) -> None:
        from ..sim.arm import get_scene

        self.server, self.root, self.kind, self.robot = server, root, kind, robot
        model = get_scene(kind, robot).model
        self.frames = {}
        pos, quat = scene3d.rest_poses(kind, robot=robot)
        self.geoms = scene3d.scene_geoms(model)
        for geom in self.geoms:
            b = geom.body
            if b not in self.frames:
                self.frames[b] = server.scene.add_frame(f"{root}/arm/body{b}", show_axes=False, position=pos[b],
                                                        wxyz=quat[b])
            # a robot's names carry its prefix ("panda/link1"): a '/' would nest a scene node under it
            server.scene.add_mesh_simple(f"{root}/arm/body{b}/{geom.name.replace('/', '__')}", geom.vertices,
                                         geom.faces, color=geom.rgb, flat_shading=False, cast_shadow=False,
                                         receive_shadow=False)  # no shadow pass: cheap redraws
        self.playing = False
        self.replay: scene3d.Replay | None = None

    @property
    def triangles(self) -> int:
        """Triangles this arm's scene sends to the page."""
        return sum(len(g.faces) for g in self.geoms)

    def pose(self, pos: np.ndarray, quat: np.ndarray) -> None:
        with self.server.atomic():
            for b, frame in self.frames.items():
                if b == 0:
                    continue
                frame.position, frame.wxyz = pos[b], quat[b]

    def rest(self, start: np.ndarray | None = None) -> None:
        self.pose(*scene3d.rest_poses(self.kind, start, robot=self.robot))


__all__ = ["MAX_LINE_POINTS", "ArmView", "SceneLine", "about_x", "polyline"]
