"""Prompt embeddings with a tiny random Qwen2.5-VL (the real transformers class), checked against
diffusers' own Cosmos-Predict2.5 pipeline method; caching, the CLI and the Hub path."""

import json
import types

import pytest
import torch
from _models import tiny_world_model
from _paths import TOYARM_ASSETS

pytest.importorskip("transformers")

from oscar_core.model.text import PromptEmbeddingCache
from oscar_core.model.text_encoder import (
    SYSTEM_PROMPT,
    TextEncoder,
    encode_prompts,
    parse_encoder_id,
    require_transformers,
)

LAYERS, HIDDEN = 3, 16  # embedding width 48 = the tiny DiT's text dimension
PROMPTS = ["put the red cup in the sink", "", "wave"]


def _tokenizer():
    from tokenizers import Tokenizer, models, pre_tokenizers
    from transformers import PreTrainedTokenizerFast

    words = sorted(set((SYSTEM_PROMPT + " system user " + " ".join(PROMPTS)).replace(".", " . ").split()))
    specials = ["<|endoftext|>", "<|im_start|>", "<|im_end|>", "[UNK]"]
    vocab = {w: i for i, w in enumerate(specials + words)}
    tok = Tokenizer(models.WordLevel(vocab, unk_token="[UNK]"))
    tok.pre_tokenizer = pre_tokenizers.Whitespace()
    hf = PreTrainedTokenizerFast(
        tokenizer_object=tok, pad_token="<|endoftext|>", eos_token="<|im_end|>", unk_token="[UNK]"
    )
    hf.add_special_tokens({"additional_special_tokens": ["<|im_start|>"]})
    # a ChatML template of the Qwen kind (the real one ships with the real tokenizer)
    hf.chat_template = (
        "{% for m in messages %}<|im_start|>{{ m['role'] }} {% for c in m['content'] %}"
        "{{ c['text'] }}{% endfor %}<|im_end|> {% endfor %}"
    )
    return hf


def _encoder(seed=0):
    from transformers import Qwen2_5_VLConfig, Qwen2_5_VLForConditionalGeneration

    cfg = Qwen2_5_VLConfig(
        text_config=dict(
            vocab_size=64,
            hidden_size=HIDDEN,
            num_hidden_layers=LAYERS,
            num_attention_heads=2,
            num_key_value_heads=1,
            intermediate_size=24,
            max_position_embeddings=1024,
            rope_scaling={"type": "mrope", "mrope_section": [1, 1, 2]},
        ),
        vision_config=dict(
            depth=1, hidden_size=8, intermediate_size=8, num_heads=2, out_hidden_size=HIDDEN, fullatt_block_indexes=[0]
        ),
    )
    torch.manual_seed(seed)
    return Qwen2_5_VLForConditionalGeneration(cfg).eval()


@pytest.fixture(scope="module")
def pipeline_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cosmos-pipe")
    _encoder().save_pretrained(folder / "text_encoder", safe_serialization=True)
    _tokenizer().save_pretrained(folder / "tokenizer")
    return folder


@pytest.fixture(autouse=True)
def isolated(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hf-cache"))
    monkeypatch.setenv("OSCAR_CACHE", str(tmp_path / "oscar-cache"))
    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)


def test_embeddings_equal_diffusers_cosmos25_pipeline(pipeline_folder):
    from diffusers.pipelines.cosmos.pipeline_cosmos2_5_predict import Cosmos2_5_PredictBasePipeline

    enc = TextEncoder.from_folder(pipeline_folder)
    # diffusers' method on an object holding the same tokenizer and encoder (the pipeline itself would
    # also need a VAE, a DiT and the guardrail package)
    holder = types.SimpleNamespace(tokenizer=enc.tokenizer, text_encoder=enc.model)
    reference = Cosmos2_5_PredictBasePipeline._get_prompt_embeds(
        holder, PROMPTS, max_sequence_length=512, device=torch.device("cpu"), dtype=torch.float32
    )
    ours = encode_prompts(enc.model, enc.tokenizer, PROMPTS)
    assert ours.shape == (3, 512, LAYERS * HIDDEN) == reference.shape
    torch.testing.assert_close(ours, reference, rtol=0, atol=0)
    assert enc.text_dim == LAYERS * HIDDEN
    # the prompts differ, so do their embeddings; each layer block is normalised (mean 0, std 1 per token)
    assert not torch.equal(ours[0], ours[1])
    block = ours[0, :, HIDDEN : 2 * HIDDEN]
    torch.testing.assert_close(block.mean(-1), torch.zeros(512), atol=1e-5, rtol=0)
    torch.testing.assert_close(block.std(-1), torch.ones(512), atol=1e-4, rtol=0)


def test_layer_normalisation_uses_every_decoder_layer_not_the_embeddings(pipeline_folder):
    enc = TextEncoder.from_folder(pipeline_folder)
    from oscar_core.model.text_encoder import prompt_input_ids

    ids = prompt_input_ids(enc.tokenizer, ["wave"])
    hidden = enc.model(ids, output_hidden_states=True).hidden_states
    assert len(hidden) == LAYERS + 1
    last = hidden[-1]
    expected = (last - last.mean(-1, keepdim=True)) / (last.std(-1, keepdim=True) + 1e-8)
    torch.testing.assert_close(enc.encode("wave")[0, :, -HIDDEN:], expected[0])
    assert ids.shape == (1, 512) and int(ids[0, -1]) == enc.tokenizer.pad_token_id  # padded to 512


def test_cache_by_prompt_and_encoder(pipeline_folder, tmp_path, monkeypatch):
    enc = TextEncoder.from_folder(pipeline_folder)
    calls = []
    real = enc.encode
    monkeypatch.setattr(enc, "encode", lambda p: calls.append(p) or real(p))
    first, hit = enc.cached("wave", tmp_path / "c")
    again, hit2 = enc.cached("wave", tmp_path / "c")
    assert (hit, hit2) == (False, True) and calls == ["wave"] and torch.equal(first, again)
    other = PromptEmbeddingCache(tmp_path / "c", encoder_id=enc.encoder_id + "-other-revision")
    assert other.get("wave") is None  # another encoder revision never reads this one's embeddings


def test_encoder_ids_and_the_missing_extra(monkeypatch):
    assert parse_encoder_id("nvidia/Cosmos-Predict2.5-2B@diffusers/base/post-trained:text_encoder") == (
        "nvidia/Cosmos-Predict2.5-2B",
        "diffusers/base/post-trained",
        "text_encoder",
    )
    assert parse_encoder_id("me/enc") == ("me/enc", None, "text_encoder")
    import sys

    monkeypatch.setitem(sys.modules, "transformers", None)
    with pytest.raises(ImportError, match=r'pip install "oscar-wm\[text\]"'):
        require_transformers()


def test_encoder_from_the_mock_hub(pipeline_folder, tmp_path):
    from oscar_zoo.testing import MockHub

    with MockHub() as hub:
        hub.add_folder("nvidia/pipe", pipeline_folder, revision="diffusers/base")
        enc = TextEncoder.from_hub("nvidia/pipe@diffusers/base:text_encoder", endpoint=hub.url)
        assert enc.encoder_id == "nvidia/pipe@diffusers/base:text_encoder"
        torch.testing.assert_close(enc.encode("wave"), TextEncoder.from_folder(pipeline_folder).encode("wave"))


def test_cli_encode_prompt_writes_cache_and_file(pipeline_folder, tmp_path, capsys):
    from oscar_core.cli import main

    out = tmp_path / "wave.safetensors"
    args = [
        "encode-prompt",
        "wave",
        "--encoder",
        str(pipeline_folder),
        "--out",
        str(out),
        "--json",
        "--prompt-cache",
        str(tmp_path / "c"),
    ]
    assert main(args) == 0
    first = json.loads(capsys.readouterr().out)
    assert first["shape"] == [1, 512, 48] and first["was_cached"] is False and out.is_file()
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out)["was_cached"] is True


@pytest.mark.slow
def test_rollout_prompt_uses_the_checkpoints_encoder_and_says_where_text_came_from(pipeline_folder, tmp_path, capsys):

    import cv2
    import numpy as np

    import oscar_zoo
    from oscar_core.cli import main

    assets = TOYARM_ASSETS
    model = tiny_world_model(name="tiny", chunk_frames=81, fps=15.0, text_encoder_id=str(pipeline_folder))
    folder = oscar_zoo.export(model, tmp_path / "m")
    first = tmp_path / "first.png"
    cv2.imwrite(str(first), np.zeros((360, 640, 3), np.uint8))
    base = [
        "rollout",
        "--model",
        str(folder),
        "--embodiment",
        "toyarm",
        "--first-frame",
        str(first),
        "--trajectory",
        str(assets / "example_trajectory.npz"),
        "--camera",
        str(assets / "example_camera.json"),
        "--size",
        "32x16",
        "--steps",
        "1",
        "--no-progress",
        "--no-side-by-side",
        "--prompt-cache",
        str(tmp_path / "c"),
        "--json",
    ]
    assert main(base + ["--out", str(tmp_path / "a.mkv"), "--prompt", "wave"]) == 0
    out, err = capsys.readouterr()
    assert "text: prompt 'wave', computed with" in err and json.loads(out)["text"].startswith("prompt 'wave'")
    assert main(base + ["--out", str(tmp_path / "b.mkv"), "--prompt", "wave"]) == 0
    assert "text: prompt 'wave', cached" in capsys.readouterr().err
    assert main(base + ["--out", str(tmp_path / "c.mkv")]) == 0  # no prompt: the encoder's empty prompt
    assert "text: empty-prompt embedding (no --prompt), computed with" in capsys.readouterr().err
