"""Synthetic scenes of solid primitives: exact ray-cast depth images and exact distances."""

from depthguard.scenes._primitives import Box, Capsule, Sphere, render_depth, scene_distance

__all__ = ["Box", "Capsule", "Sphere", "render_depth", "scene_distance"]
