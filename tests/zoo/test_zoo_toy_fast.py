"""The bundled few-step student ``oscar-toy-fast``: loads by name offline, samples a chunk in 4 DiT evaluations of
one branch from its card alone, and shares its teacher's VAE and empty prompt byte for byte."""

from __future__ import annotations

import numpy as np
import torch

import oscar_zoo
from oscar_core.model.sampler import model_calls


def _spec(name):
    return next(s for s in oscar_zoo.CHECKPOINTS if s.name == name)


def test_the_student_samples_a_chunk_in_four_evaluations_from_its_card_alone(one_thread):
    student = oscar_zoo.load("oscar-toy-fast")  # bundled: offline, every file's sha256 checked
    assert student.card.name == "oscar-toy-fast"
    assert student.card.sampler == {"steps": 4, "guidance": None, "guidance_form": "diffusers", "preset": None}
    sampler = student.sampler_for(student.recommended_sampler())
    assert (sampler.resolved_solver, sampler.steps, sampler.guidance) == ("euler", 4, None)
    assert model_calls(sampler) == 4

    calls = []
    forward = student.transformer.forward

    def counted(*a, **kw):
        calls.append(int(kw["hidden_states"].shape[0]))
        return forward(*a, **kw)

    student.transformer.forward = counted
    first = np.full((64, 64, 3), 90, np.uint8)
    skeleton = np.zeros((17, 64, 64, 3), np.uint8)
    for t in range(17):  # a bar that moves right: something to follow
        skeleton[t, 20:40, 10 + 2 * t : 14 + 2 * t] = 255
    out = student.rollout(first, skeleton, student.prompt_embeds(), progress=False, seed=0)
    student.transformer.forward = forward
    assert calls == [1, 1, 1, 1]  # one chunk: 4 evaluations of batch 1, no unconditional branch
    assert out.frames.shape == (17, 64, 64, 3) and out.frames.dtype == np.uint8
    assert torch.isfinite(torch.as_tensor(out.frames, dtype=torch.float32)).all()


def test_the_student_ships_its_teachers_vae_and_empty_prompt():
    teacher, student = _spec("oscar-toy"), _spec("oscar-toy-fast")
    assert student.bundled and student.embodiments == teacher.embodiments
    assert (student.chunk_frames, student.width, student.height, student.fps) == (
        teacher.chunk_frames,
        teacher.width,
        teacher.height,
        teacher.fps,
    )
    pins = {f.path: f.sha256 for f in teacher.files}
    shared = [f for f in student.files if f.path.startswith(("vae/", "text/"))]
    assert len(shared) == 3 and all(pins[f.path] == f.sha256 for f in shared)
    size = sum(f.stat().st_size for f in oscar_zoo.pull("oscar-toy-fast").rglob("*") if f.is_file())
    assert size < 20e6, f"oscar-toy-fast is {size / 1e6:.1f} MB"
    weights = "transformer/diffusion_pytorch_model.safetensors"
    assert {f.path: f.sha256 for f in student.files}[weights] != pins[weights]  # distilled, not a copy
