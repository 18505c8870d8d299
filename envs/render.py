"""Top-down rendering of scenarios and roll-outs (offscreen pygame, no display needed).

The road is drawn once per road and view into a background: drivable area (union of lane polygons) in dark
grey, then highway-env's ``LaneGraphics`` for the lane borders (``continuous`` solid, ``striped`` dashed) on a
y-mirrored network (`seal.envs.road_network`) so the world appears with y up. Vehicles are drawn as oriented boxes:
ego green, adversary red, others blue, with their recent path. Everything is drawn on plain
``pygame.Surface`` objects (highway-env's own viewer renders blank frames under ``SDL_VIDEODRIVER=dummy``).

`seal.envs.episode_video.render_episode` runs one episode and writes it with `write_video`.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, cast

import numpy as np

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")  # no banner on stdout: `seal render` prints JSON
import pygame  # noqa: E402
import shapely
from highway_env.road.graphics import LaneGraphics, WorldSurface
from highway_env.road.lane import LineType

from seal.core.road import RoadDescription
from seal.core.scenario import CURRENT_STEP, HEADING, LENGTH, VALID, WIDTH, Scenario, X, Y
from seal.envs.road_geometry import get_road_geometry
from seal.envs.road_network import build_road_network
from seal.envs.rollout import Rollout

GRASS = (96, 118, 96)
ROAD = (70, 70, 74)
EGO = (60, 200, 60)
ADV = (230, 50, 50)
OTHER = (70, 130, 230)
ROUTE = (170, 230, 170)
TEXT = (255, 255, 255)
MAX_FRAME = (1280, 720)
MIN_VIEW_M = (80.0, 50.0)


def _even16(n: float) -> int:
    return max(16, int(math.ceil(n / 16.0)) * 16)


class FrameRenderer:
    """Draws frames of one road for a fixed view (``bounds``) or a window following a point.

    Args:
        road: the road.
        bounds: ``(xmin, ymin, xmax, ymax)`` world metres to show; None: follow mode, a ``follow_size_m`` window.
        max_frame: largest frame size in pixels (width, height); sizes are rounded to multiples of 16 (video
            codecs).
        follow_size_m: window size in metres for follow mode.
    """

    def __init__(
        self, road: RoadDescription, bounds: tuple[float, float, float, float] | None = None,
        max_frame: tuple[int, int] = MAX_FRAME, follow_size_m: tuple[float, float] = (120.0, 70.0),
    ) -> None:
        pygame.font.init()
        self.road = road
        self.follow = bounds is None
        if bounds is None:
            w_m, h_m = follow_size_m
        else:
            w_m, h_m = bounds[2] - bounds[0], bounds[3] - bounds[1]
        self.scale = min(max_frame[0] / w_m, max_frame[1] / h_m)
        self.size = (_even16(w_m * self.scale), _even16(h_m * self.scale))
        self.bounds = bounds
        self._network = build_road_network(road, mirror_y=True)
        self._font = pygame.font.Font(None, max(16, self.size[1] // 28))
        self._bg: pygame.Surface | None = None
        self._bg_origin = (0.0, 0.0)  # world (x, y_top) of the background's top-left pixel
        if bounds is not None:
            cx, cy = (bounds[0] + bounds[2]) / 2, (bounds[1] + bounds[3]) / 2
            self._make_background(cx, cy, self.size)

    # ----------------------------------------------------------------------------------------- geometry
    def _make_background(self, cx: float, cy: float, size: tuple[int, int]) -> None:
        """Draw the road into a background of ``size`` pixels centred on world (cx, cy)."""
        w_m, h_m = size[0] / self.scale, size[1] / self.scale
        x0, y_top = cx - w_m / 2, cy + h_m / 2
        surf = WorldSurface(size, 0, pygame.Surface(size))
        surf.scaling = self.scale
        surf.origin = np.array([x0, -y_top])  # mirrored network: screen y = -(world y)
        surf.fill(GRASS)
        area = get_road_geometry(self.road).drivable
        for poly in getattr(area, "geoms", [area]):
            if not isinstance(poly, shapely.Polygon):
                continue
            pygame.draw.polygon(surf, ROAD, [self._pix(x, y, x0, y_top) for x, y in poly.exterior.coords])
            for ring in poly.interiors:
                pygame.draw.polygon(surf, GRASS, [self._pix(x, y, x0, y_top) for x, y in ring.coords])
        for lanes in (lane for to in self._network.graph.values() for ls in to.values() for lane in ls):
            lane = lanes
            # Draw stripes over the whole lane (LaneGraphics.display only covers a window around the origin).
            count = int(lane.length / LaneGraphics.STRIPE_SPACING) + 2
            for side in range(2):
                kind = lane.line_types[side]
                if kind == LineType.STRIPED:
                    LaneGraphics.striped_line(lane, surf, count, 0.0, side)
                elif kind == LineType.CONTINUOUS:
                    LaneGraphics.continuous_curve(lane, surf, count, 0.0, side)
        self._bg = surf
        self._bg_origin = (x0, y_top)

    def _pix(self, x: float, y: float, x0: float, y_top: float) -> tuple[int, int]:
        return int((x - x0) * self.scale), int((y_top - y) * self.scale)

    # ----------------------------------------------------------------------------------------- drawing
    def draw_state(
        self,
        agents: np.ndarray,
        ego_index: int,
        adv_index: int,
        follow: tuple[float, float] | None = None,
        text: str = "",
        trails: dict[int, np.ndarray] | None = None,
        route: np.ndarray | None = None,
    ) -> np.ndarray:
        """Frame ``[H, W, 3]`` uint8 of agents ``[A, 8]`` (track layout; invalid rows skipped).

        Args:
            follow: world point to centre on (follow mode).
            trails: agent index -> ``[K, 2]`` past positions to draw as a line.
            route: ``[P, 2]`` route polyline drawn faintly (e.g. the logged ego route).
        """
        if self.follow:
            cx, cy = follow if follow is not None else (0.0, 0.0)
            w_m, h_m = self.size[0] / self.scale, self.size[1] / self.scale
            x0, y_top = cx - w_m / 2, cy + h_m / 2
            bx0, by_top = self._bg_origin
            bw, bh = (self._bg.get_width() / self.scale, self._bg.get_height() / self.scale) if self._bg else (0, 0)
            if self._bg is None or x0 < bx0 or y_top > by_top or x0 + w_m > bx0 + bw or y_top - h_m < by_top - bh:
                # Re-centre a background three windows wide on the point (redrawn rarely).
                self._make_background(cx, cy, (self.size[0] * 3, self.size[1] * 3))
                bx0, by_top = self._bg_origin
            bg = self._bg
            assert bg is not None  # drawn just above when missing
            frame = pygame.Surface(self.size)
            frame.blit(bg, (0, 0), pygame.Rect(int((x0 - bx0) * self.scale), int((by_top - y_top) * self.scale),
                                                     *self.size))
        else:
            x0, y_top = self._bg_origin
            assert self._bg is not None  # a fixed view draws its background in __init__
            frame = self._bg.copy()

        if route is not None and len(route) > 1:
            pygame.draw.lines(frame, ROUTE, False, [self._pix(x, y, x0, y_top) for x, y in route], 1)
        for idx, pts in (trails or {}).items():
            if len(pts) > 1:
                color = EGO if idx == ego_index else ADV if idx == adv_index else OTHER
                pygame.draw.lines(frame, color, False, [self._pix(x, y, x0, y_top) for x, y in pts], 2)
        order = [i for i in range(len(agents)) if i not in (ego_index, adv_index)] + [adv_index, ego_index]
        for i in order:
            row = agents[i]
            if row[VALID] < 0.5:
                continue
            color = EGO if i == ego_index else ADV if i == adv_index else OTHER
            self._draw_box(frame, row, color, x0, y_top)
        if text:
            for k, line in enumerate(self.wrap_text(text)):
                img = self._font.render(line, True, TEXT, (0, 0, 0))
                frame.blit(img, (6, 6 + k * (img.get_height() + 2)))
        return np.ascontiguousarray(pygame.surfarray.array3d(frame).swapaxes(0, 1))

    def wrap_text(self, text: str) -> list[str]:
        """``text`` as lines that fit the frame (6 px margins): each line of it broken at spaces (a single word
        wider than the frame is cut), so a title is not cut off on a narrow frame."""
        room = self.size[0] - 12
        out: list[str] = []
        for line in text.split("\n"):
            current = ""
            for word in line.split(" "):
                trial = f"{current} {word}" if current else word
                if current and self._font.size(trial)[0] > room:
                    out.append(current)
                    trial = word
                while len(trial) > 1 and self._font.size(trial)[0] > room:
                    trial = trial[:-1]
                current = trial
            out.append(current)
        return out

    def _draw_box(self, frame: pygame.Surface, row: np.ndarray, color: tuple[int, int, int], x0: float,
                  y_top: float) -> None:
        c, s = math.cos(row[HEADING]), math.sin(row[HEADING])
        hl, hw = row[LENGTH] / 2, row[WIDTH] / 2
        corners = [(hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw)]
        pts = [self._pix(row[X] + a * c - b * s, row[Y] + a * s + b * c, x0, y_top) for a, b in corners]
        pygame.draw.polygon(frame, color, pts)
        pygame.draw.polygon(frame, (20, 20, 20), pts, 1)
        # Windscreen mark at the front third so the heading is visible.
        f = [self._pix(row[X] + a * c - b * s, row[Y] + a * s + b * c, x0, y_top)
             for a, b in ((hl * 0.45, hw * 0.8), (hl * 0.45, -hw * 0.8))]
        pygame.draw.line(frame, (20, 20, 20), f[0], f[1], max(1, int(self.scale * 0.25)))


def rollout_bounds(rollout: Rollout, route: np.ndarray | None = None, margin_m: float = 25.0
                   ) -> tuple[float, float, float, float]:
    """View covering the ego's and adversary's executed tracks (and ``route``), with a margin."""
    pts = []
    for tr in (rollout.ego_track, rollout.adv_track):
        v = tr[:, VALID] > 0.5
        pts.append(tr[v][:, [X, Y]])
    if route is not None:
        pts.append(route)
    p = np.concatenate(pts)
    xmin, ymin = p.min(0) - margin_m
    xmax, ymax = p.max(0) + margin_m
    w, h = max(xmax - xmin, MIN_VIEW_M[0]), max(ymax - ymin, MIN_VIEW_M[1])
    cx, cy = (xmin + xmax) / 2, (ymin + ymax) / 2
    return float(cx - w / 2), float(cy - h / 2), float(cx + w / 2), float(cy + h / 2)


def render_rollout(rollout: Rollout, road: RoadDescription, scenario: Scenario | None = None,
                   trail_steps: int = 30, adversary_label: str | None = None, ego_label: str | None = None
                   ) -> list[np.ndarray]:
    """Frames (one per executed step, from ``CURRENT_STEP``) of a roll-out on a fixed view. The caption names the
    adversary (``adversary_label``, e.g. the generator; default: its behaviour class) and the ego
    (``ego_label``, when given)."""
    route = None
    if scenario is not None:
        tr = scenario.track(scenario.ego_id)
        route = tr[tr[:, VALID] > 0.5][:, [X, Y]]
    renderer = FrameRenderer(road, bounds=rollout_bounds(rollout, route))
    ego, adv = rollout.index_of(rollout.ego_id), rollout.index_of(rollout.adv_id)
    crash_at = {step: other for step, other in rollout.ego_crashes}
    frames = []
    events: list[str] = []
    for t in range(CURRENT_STEP, rollout.last_step + 1):
        agents = rollout.tracks[:, t]
        if t in crash_at and not any(e.startswith("crash") for e in events):
            events.append(f"crash with {crash_at[t]}{' (adversary)' if crash_at[t] == rollout.adv_id else ''}")
        if rollout.out_of_road_step == t:
            events.append("out of road")
        if rollout.success_step == t:
            events.append("arrived")
        trails = {}
        for i in (ego, adv):
            seg = rollout.tracks[i, max(0, t - trail_steps) : t + 1]
            trails[i] = seg[seg[:, VALID] > 0.5][:, [X, Y]]
        speed = float(np.hypot(*agents[ego, 3:5]))
        text = (f"{rollout.scenario_id}  t={(t - CURRENT_STEP) / 10:4.1f}s  step {t}  ego {speed:4.1f} m/s"
                f"\nadversary: {adversary_label or rollout.adversary}" + (f"  ego: {ego_label}" if ego_label else "")
                + (f"\n{', '.join(events)}" if events else ""))
        frames.append(renderer.draw_state(agents, ego, adv, text=text, trails=trails, route=route))
    return frames


def write_video(frames: list[np.ndarray], out_path: str | Path, fps: int = 10) -> Path:
    """Write frames as ``.mp4`` (libx264 via imageio-ffmpeg) or ``.gif`` (by the suffix)."""
    import imageio.v2 as imageio

    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.suffix.lower() == ".gif":
        imageio.mimsave(out, cast("list[Any]", frames), duration=1000.0 / fps, loop=0)  # its stubs want list[ArrayLike]
    elif out.suffix.lower() == ".mp4":
        with imageio.get_writer(out, fps=fps, codec="libx264", macro_block_size=16, quality=7) as writer:
            for f in frames:
                # imageio's stubs type get_writer as its base reader/writer; the writer it returns has append_data.
                writer.append_data(f)  # type: ignore[attr-defined]
    else:
        raise ValueError(f"unsupported video format {out.suffix!r}: use .mp4 or .gif")
    return out
