"""oscar: skeleton-conditioned video world models for any robot body.

The public API is re-exported here; submodules load on first use so that
``import oscar_core`` (and the pytest plugin) stays fast.
"""

from __future__ import annotations

from ._lazy import lazy_exports

__version__ = "0.1.0"

_EXPORTS = {
    # plugin contract
    "hookimpl": "hookspecs", "hookspec": "hookspecs",
    "Embodiment": "embodiment", "Gripper": "embodiment", "CameraSpec": "embodiment",
    "SkeletonFrames": "embodiment", "JointLimitWarning": "embodiment",
    "DefaultPoseWarning": "embodiment",
    "Skeleton": "skeleton",
    "Registry": "registry", "default_registry": "registry", "get_embodiment": "registry",
    # kinematics
    "KinematicTree": "urdf", "build_tree_from_urdf": "urdf", "build_tree_from_xacro": "urdf",
    "ForwardKinematics": "kinematics",
    # trajectories and cameras
    "Trajectory": "trajectory", "load_trajectory": "trajectory", "save_trajectory": "trajectory",
    "interpolate_keyframes": "trajectory", "look_at": "camera",
    "Camera": "camera", "Intrinsics": "camera", "load_camera": "camera", "save_camera": "camera", "project": "camera",
    # rendering and video
    "SkeletonStyle": "render", "GripperMarks": "render", "rasterise": "render",
    "render_skeleton_video": "pipeline", "overlay_skeleton": "pipeline",
    "render_mesh_video": "mesh_render", "MeshStyle": "mesh_render", "VisualGeometry": "visual",
    "LinkGeometry": "visual",
    "write_video": "video", "read_video": "video",
    # errors
    "OscarError": "errors", "InputFileError": "errors", "CameraFileError": "errors", "KinematicsFileError": "errors",
    "TrajectoryError": "errors", "OutputPathError": "errors", "PluginError": "errors",
}

_names, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
__all__ = _names + ["__version__"]
