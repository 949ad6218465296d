"""Rendering of triangle meshes into pinhole cameras with OpenGL (headless EGL): exact depth through each pixel
centre, labels, a Lambertian intensity image, and the depth of the farthest surface (where a body ends).

Typical use (the robot's collision meshes for self-filtering, design §7)::

    from depthguard.rendering import MeshInstance, Renderer, primitive_mesh
    renderer = Renderer()                                   # one EGL context, reused
    link = renderer.add_mesh(vertices, faces)               # once, in the link's frame
    near = renderer.render_depth(camera, [MeshInstance(link, T_world_link, label=3)])
    far = renderer.render_depth_max(camera, [MeshInstance(link, T_world_link, label=3)])
"""

from depthguard.rendering._meshes import primitive_mesh, primitive_mesh_excess
from depthguard.rendering._renderer import MeshInstance, Renderer, RenderResult

__all__ = ["MeshInstance", "RenderResult", "Renderer", "primitive_mesh", "primitive_mesh_excess"]
