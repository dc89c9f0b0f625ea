"""The pymunk world: static walls and a circular differential-drive robot.

Chipmunk moves a body by its velocity before it resolves contacts, so a velocity set from
outside drives the robot through walls; the command is applied inside the body's
``velocity_func`` instead, and contacts then stop it at the wall (a few cm of overlap at most).
``collision_slop`` is set for metres (Chipmunk's default assumes pixels).
"""

from __future__ import annotations

import math

import numpy as np
import pymunk

from swarmslam_sim.world import World

WALL, ROBOT = 1, 2
_SET_VELOCITY = pymunk.Body.velocity.fset
_SET_ANGULAR_VELOCITY = pymunk.Body.angular_velocity.fset
SUBSTEP = 0.05  # s, the longest physics step (2.5 cm at 0.5 m/s, far less than the radius)


class Robot:
    """A circular differential-drive body; ``command(v, ω)`` sets the wheel velocities."""

    def __init__(self, space: pymunk.Space, pose, radius: float = 0.17, mass: float = 4.0):
        self.radius = radius
        self.body = pymunk.Body(mass, pymunk.moment_for_circle(mass, 0, radius))
        self.body.position = (float(pose[0]), float(pose[1]))
        self.body.angle = float(pose[2])
        self.body.velocity_func = self._drive
        self.shape = pymunk.Circle(self.body, radius)
        self.shape.collision_type = ROBOT
        self.shape.friction = 0.0
        self.linear = 0.0
        self.angular = 0.0
        self.contacts = 0  # walls touching now
        self.touched = False  # a wall touched since clear_touched()
        space.add(self.body, self.shape)
        space.on_collision(ROBOT, WALL, begin=self._begin, separate=self._separate)

    def command(self, linear: float, angular: float) -> None:
        self.linear, self.angular = float(linear), float(angular)

    def _drive(self, body, gravity, damping, dt):
        # no lateral slip: the wheels push along the heading only (the properties' setters
        # called directly: pymunk's __setattr__ hook, there for type checkers, costs as much)
        angle = body.angle
        _SET_VELOCITY(body, (self.linear * math.cos(angle), self.linear * math.sin(angle)))
        _SET_ANGULAR_VELOCITY(body, self.angular)

    @property
    def pose(self) -> np.ndarray:
        p = self.body.position
        return np.array([p.x, p.y, self.body.angle])

    def _begin(self, arbiter, space, data):
        self.contacts += 1
        self.touched = True

    def _separate(self, arbiter, space, data):
        self.contacts -= 1

    def clear_touched(self) -> None:
        self.touched = self.contacts > 0


def build_space(world: World, wall_radius: float = 0.0) -> pymunk.Space:
    space = pymunk.Space()
    space.collision_slop = 0.001  # metres, not pixels
    static = space.static_body
    for x0, y0, x1, y1 in world.segments:
        wall = pymunk.Segment(static, (x0, y0), (x1, y1), wall_radius)
        wall.collision_type = WALL
        wall.friction = 0.0
        space.add(wall)
    return space


def pymunk_scan(space: pymunk.Space, pose, angles, max_range: float) -> np.ndarray:
    """Reference ranges by per-beam ``segment_query_first`` (slow; for tests and benchmarks).

    Only wall shapes are hit (the robot's own circle is filtered out); inf where none lies
    within ``max_range``."""
    walls_only = pymunk.ShapeFilter(categories=1, mask=pymunk.ShapeFilter.ALL_MASKS())
    out = np.full(len(angles), np.inf)
    x, y, th = pose
    for k, a in enumerate(angles):
        end = (x + max_range * math.cos(th + a), y + max_range * math.sin(th + a))
        hit = space.segment_query_first((x, y), end, 0.0, walls_only)
        if hit is not None and hit.shape.collision_type == WALL:
            out[k] = hit.alpha * max_range
    return out
