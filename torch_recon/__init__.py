"""platolidar reconstructor: two-bounce lidar measurements -> geometry -> mesh.

Importing this package is cheap and never imports torch or bpy: the numpy-only
parts (units, frames, dataset format) are shared with the Blender-side pipeline.
"""

__version__ = "0.1.0"
