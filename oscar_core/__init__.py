"""oscar: skeleton-conditioned video world models for any robot body.

The public API is re-exported here; submodules load on first use so that
``import oscar_core`` (and the pytest plugin) stays fast.
"""

from __future__ import annotations

from ._util.lazy import lazy_exports

__version__ = "0.1.0"

_EXPORTS = {
    # plugin contract
    "hookimpl": "plugin.hookspecs", "hookspec": "plugin.hookspecs",
    "Embodiment": "plugin.embodiment", "Gripper": "plugin.embodiment", "CameraSpec": "plugin.embodiment",
    "SkeletonFrames": "plugin.embodiment", "JointLimitWarning": "plugin.embodiment",
    "DefaultPoseWarning": "plugin.embodiment",
    "Skeleton": "plugin.skeleton",
    "Registry": "plugin.registry", "default_registry": "plugin.registry", "get_embodiment": "plugin.registry",
    # kinematics
    "KinematicTree": "kinematics.urdf", "build_tree_from_urdf": "kinematics.urdf", "build_tree_from_xacro": "kinematics.urdf",
    "ForwardKinematics": "kinematics.fk_torch",
    # trajectories and cameras
    "Trajectory": "kinematics.trajectory", "load_trajectory": "kinematics.trajectory", "save_trajectory": "kinematics.trajectory",
    "interpolate_keyframes": "kinematics.trajectory", "look_at": "camera",
    "Camera": "camera", "Intrinsics": "camera", "load_camera": "camera", "save_camera": "camera", "project": "camera",
    # rendering and video
    "SkeletonStyle": "render.raster", "GripperMarks": "render.raster", "rasterise": "render.raster",
    "render_skeleton_video": "render.skeleton_video", "overlay_skeleton": "render.skeleton_video",
    "render_mesh_video": "render.mesh", "MeshStyle": "render.mesh", "VisualGeometry": "kinematics.visual",
    "LinkGeometry": "kinematics.visual",
    "write_video": "media.video", "read_video": "media.video",
    # errors
    "OscarError": "errors", "InputFileError": "errors", "CameraFileError": "errors", "KinematicsFileError": "errors",
    "TrajectoryError": "errors", "OutputPathError": "errors", "PluginError": "errors",
}

_names, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
__all__ = _names + ["__version__"]
