"""``oscar eval run`` rolls a mesh-conditioned model out on the mesh video (the card's condition)."""

import cv2
import numpy as np
from _models import tiny_world_model
from _paths import TOYARM_ASSETS

from oscar_core import get_embodiment, load_camera, load_trajectory
from oscar_core.evaluation.manifest import Cell
from oscar_core.evaluation.rollout_engines import cell_inputs, roll_out_group
from oscar_core.model.sampler import SamplerConfig
from oscar_core.render.mesh import render_mesh_video
from oscar_core.render.skeleton_video import render_skeleton_video


def test_a_cell_of_a_mesh_model_is_conditioned_on_the_mesh(tmp_path):
    first = tmp_path / "first.png"
    cv2.imwrite(str(first), np.full((360, 640, 3), 90, np.uint8))
    traj_path = tmp_path / "t.npz"
    traj = load_trajectory(TOYARM_ASSETS / "example_trajectory.npz").time_slice(0, 9)
    from oscar_core import save_trajectory

    save_trajectory(traj, traj_path)
    cell = Cell("s", "p", "task", "toyarm", first, traj_path, TOYARM_ASSETS / "example_camera.json", 0)
    seen = {}
    for condition in ("mesh", "skeleton"):
        model = tiny_world_model(name="m", chunk_frames=9, fps=15.0, condition=condition)

        def spy(first_frame, skeleton, *args, _rollout=model.rollout, _condition=condition, **kwargs):
            seen[_condition] = skeleton
            return _rollout(first_frame, skeleton, *args, **kwargs)

        model.rollout = spy
        inputs = cell_inputs(model, cell, (64, 32), plugin_paths=())
        (frames,) = roll_out_group(
            model, [inputs], sampler=SamplerConfig(steps=1), chunk_frames=9, seeds=[cell.seed], progress=False
        )
        assert frames.shape == (9, 32, 64, 3)
    emb, cam = get_embodiment("toyarm"), load_camera(TOYARM_ASSETS / "example_camera.json")
    np.testing.assert_array_equal(seen["mesh"], render_mesh_video(emb, traj, cam, (64, 32)))
    np.testing.assert_array_equal(seen["skeleton"], render_skeleton_video(emb, traj, cam, (64, 32)))
