"""oscar: skeleton-conditioned video world models for any robot body.

The public API is re-exported here; submodules load on first use so that
``import oscar_core`` (and the pytest plugin) stays fast.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ._util.lazy import lazy_exports

__version__ = "0.2.0"  # also in pyproject.toml; CHANGELOG.md's top version (tests/project/test_public_api.py)

_EXPORTS = {
    # plugin contract
    "hookimpl": "plugin.hookspecs",
    "hookspec": "plugin.hookspecs",
    "Embodiment": "plugin.embodiment",
    "Gripper": "plugin.embodiment",
    "CameraSpec": "plugin.embodiment",
    "SkeletonFrames": "plugin.embodiment",
    "JointLimitWarning": "plugin.embodiment",
    "DefaultPoseWarning": "plugin.embodiment",
    "Skeleton": "plugin.skeleton",
    "Registry": "plugin.registry",
    "default_registry": "plugin.registry",
    "get_embodiment": "plugin.registry",
    # kinematics
    "KinematicTree": "kinematics.urdf",
    "build_tree_from_urdf": "kinematics.urdf",
    "build_tree_from_xacro": "kinematics.urdf",
    "ForwardKinematics": "kinematics.fk_torch",
    # trajectories and cameras
    "Trajectory": "kinematics.trajectory",
    "load_trajectory": "kinematics.trajectory",
    "save_trajectory": "kinematics.trajectory",
    "interpolate_keyframes": "kinematics.trajectory",
    "look_at": "camera",
    "Camera": "camera",
    "Intrinsics": "camera",
    "load_camera": "camera",
    "save_camera": "camera",
    "project": "camera",
    # rendering and video
    "SkeletonStyle": "render.raster",
    "GripperMarks": "render.raster",
    "rasterise": "render.raster",
    "render_skeleton_video": "render.skeleton_video",
    "overlay_skeleton": "render.skeleton_video",
    "render_mesh_video": "render.mesh",
    "MeshStyle": "render.mesh",
    "VisualGeometry": "kinematics.visual",
    "LinkGeometry": "kinematics.visual",
    "write_video": "media.video",
    "read_video": "media.video",
    # errors
    "OscarError": "errors",
    "InputFileError": "errors",
    "CameraFileError": "errors",
    "KinematicsFileError": "errors",
    "TrajectoryError": "errors",
    "OutputPathError": "errors",
    "PluginError": "errors",
    # deprecations (docs/api.md)
    "OscarDeprecationWarning": "_util.deprecation",
}

if (
    TYPE_CHECKING
):  # the same names, imported eagerly for type checkers only (tests/project/test_public_api.py keeps them in step)
    from ._util.deprecation import (
        OscarDeprecationWarning as OscarDeprecationWarning,
    )
    from .camera import (
        Camera as Camera,
        Intrinsics as Intrinsics,
        load_camera as load_camera,
        look_at as look_at,
        project as project,
        save_camera as save_camera,
    )
    from .errors import (
        CameraFileError as CameraFileError,
        InputFileError as InputFileError,
        KinematicsFileError as KinematicsFileError,
        OscarError as OscarError,
        OutputPathError as OutputPathError,
        PluginError as PluginError,
        TrajectoryError as TrajectoryError,
    )
    from .kinematics.fk_torch import (
        ForwardKinematics as ForwardKinematics,
    )
    from .kinematics.trajectory import (
        Trajectory as Trajectory,
        interpolate_keyframes as interpolate_keyframes,
        load_trajectory as load_trajectory,
        save_trajectory as save_trajectory,
    )
    from .kinematics.urdf import (
        KinematicTree as KinematicTree,
        build_tree_from_urdf as build_tree_from_urdf,
        build_tree_from_xacro as build_tree_from_xacro,
    )
    from .kinematics.visual import (
        LinkGeometry as LinkGeometry,
        VisualGeometry as VisualGeometry,
    )
    from .media.video import (
        read_video as read_video,
        write_video as write_video,
    )
    from .plugin.embodiment import (
        CameraSpec as CameraSpec,
        DefaultPoseWarning as DefaultPoseWarning,
        Embodiment as Embodiment,
        Gripper as Gripper,
        JointLimitWarning as JointLimitWarning,
        SkeletonFrames as SkeletonFrames,
    )
    from .plugin.hookspecs import (
        hookimpl as hookimpl,
        hookspec as hookspec,
    )
    from .plugin.registry import (
        Registry as Registry,
        default_registry as default_registry,
        get_embodiment as get_embodiment,
    )
    from .plugin.skeleton import (
        Skeleton as Skeleton,
    )
    from .render.mesh import (
        MeshStyle as MeshStyle,
        render_mesh_video as render_mesh_video,
    )
    from .render.raster import (
        GripperMarks as GripperMarks,
        SkeletonStyle as SkeletonStyle,
        rasterise as rasterise,
    )
    from .render.skeleton_video import (
        overlay_skeleton as overlay_skeleton,
        render_skeleton_video as render_skeleton_video,
    )

_names, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
__all__ = _names + ["__version__"]

# the toy world's Gymnasium ids (oscar/ToySim-v0, oscar/ToyWorldModel-v0), registered once gymnasium is imported
from ._util.gym_ids import install as _install_gym_ids  # noqa: E402

_install_gym_ids()
