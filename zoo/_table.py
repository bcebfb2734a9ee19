"""The table of named checkpoints (timm's ``pretrained_cfg`` idea, as frozen dataclasses).

Every entry pins a Hub ``repo_id`` and ``revision`` and states the license,
the paper, the embodiments it was trained on and the frames / resolution /
fps it expects. What could not be verified is left as None, never guessed:

* ``oscar-2b`` (``zywu2115/OSCAR-2B``): the paper's release. Its file layout,
  license, commit and file hashes were not available to verify: revision is
  None (the loader uses "main" and says it is unpinned), every sha256 is
  None, and the loader detects its layout from the repository listing
  (oscar's, diffusers' or a native Cosmos checkpoint:
  ``oscar_core.model.layouts``), reporting the files found, the layouts
  tried and what each expected when none matches. ``oscar zoo pull``
  pins the commit it saw in a lock file. Frames (81-frame training windows)
  and resolution (512x288, "native" in the paper's appendix) are from the
  paper; its fps is not stated there.
* ``cosmos-predict2.5-2b`` (``nvidia/Cosmos-Predict2.5-2B``, revision
  ``diffusers/base/post-trained``, a branch name as given by diffusers'
  Cosmos 2.5 pipeline docs): the base for fine-tuning; loading it gives an
  OSCAR model equal to the base (zero PE_s). The branch is not a commit
  hash (no commit could be verified here), and no sha256 is known for its
  files. Defaults (93 frames, 1280x704, 16 fps) are those of diffusers'
  ``Cosmos2_5_PredictBasePipeline`` (its ``__call__`` defaults and example).

* ``oscar-toy`` (bundled: ``zoo/assets/oscar-toy``, shipped inside the
  package, loaded offline): the toy world's model (docs/toyworld.md), a 1.8 M
  parameter DiT and 0.69 M parameter VAE trained on this project's CPU; the
  sha256 of every file it ships is pinned here.
* ``oscar-toy-fast`` (bundled, ``zoo/assets/oscar-toy-fast``): ``oscar-toy``
  distilled to a 4-step student (docs/distillation.md): 4 Euler steps of one
  conditional branch per chunk, guidance folded in; the teacher's VAE.

File hashes that are None are still checked for integrity after download:
the safetensors structure of every weight file (partial/corrupted files),
and the sha256 manifest when a checkpoint ships one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["FileSpec", "CheckpointSpec", "CHECKPOINTS", "KINDS", "COSMOS_TEXT_ENCODER_ID"]

KINDS = ("oscar", "cosmos-base")

#: Cache key of prompt embeddings made by the Cosmos-Predict2.5 text encoder (Cosmos-Reason1 / Qwen2.5-VL-7B).
COSMOS_TEXT_ENCODER_ID = "nvidia/Cosmos-Predict2.5-2B@diffusers/base/post-trained:text_encoder"


@dataclass(frozen=True)
class FileSpec:
    """A file expected in a checkpoint: path inside the repository, sha256 (hex) when known."""

    path: str
    sha256: str | None = None


@dataclass(frozen=True)
class CheckpointSpec:
    """A named checkpoint.

    kind: "oscar" (oscar's folder layout: oscar_model.json, transformer/, vae/)
        or "cosmos-base" (a diffusers Cosmos-Predict2.5 repo: transformer/, vae/);
        informative only: the loader detects the layout from the files.
    revision: branch, tag or commit on the Hub; None = "main", unpinned.
    files: files checked after download; the loader fetches what the layout
        needs (configs, single or sharded safetensors) in any case.
    bundled: a folder inside the ``oscar_zoo`` package that holds the
        checkpoint (shipped with the library, loaded offline, every file's
        sha256 pinned in ``files``); None for checkpoints on the Hub.
    chunk_frames, width, height, fps: what the model expects (None: unknown).
    """

    name: str
    repo_id: str
    revision: str | None
    kind: str
    license: str | None
    paper: str | None
    embodiments: tuple[str, ...] = ()
    chunk_frames: int | None = None
    width: int | None = None
    height: int | None = None
    fps: float | None = None
    files: tuple[FileSpec, ...] = ()
    text_encoder_id: str | None = None
    notes: str = ""
    bundled: str | None = None
    source: str = field(default="table", compare=False)

    @property
    def pinned(self) -> bool:
        """True when ``revision`` is a full commit hash."""
        r = self.revision or ""
        return len(r) == 40 and all(c in "0123456789abcdef" for c in r)

    def row(self) -> dict:
        """A JSON-ready summary (``oscar zoo list --json``)."""
        return {
            "name": self.name,
            "repo_id": self.repo_id,
            "revision": self.revision or "main (unpinned)",
            "kind": self.kind,
            "license": self.license,
            "paper": self.paper,
            "embodiments": list(self.embodiments),
            "chunk_frames": self.chunk_frames,
            "resolution": f"{self.width}x{self.height}" if self.width and self.height else None,
            "fps": self.fps,
            "files": {f.path: f.sha256 for f in self.files},
            "source": self.source,
            "notes": self.notes,
            "bundled": self.bundled,
        }


_OSCAR_LAYOUT = (FileSpec("oscar_model.json"), FileSpec("transformer/config.json"), FileSpec("vae/config.json"))

CHECKPOINTS: tuple[CheckpointSpec, ...] = tuple(
    sorted(
        (
            CheckpointSpec(
                name="cosmos-predict2.5-2b",
                repo_id="nvidia/Cosmos-Predict2.5-2B",
                revision="diffusers/base/post-trained",
                kind="cosmos-base",
                license="NVIDIA Open Model License",
                paper="arXiv:2511.00062 (World simulation with video foundation models for physical AI)",
                embodiments=(),
                chunk_frames=93,
                width=1280,
                height=704,
                fps=16.0,
                files=(FileSpec("transformer/config.json"), FileSpec("vae/config.json")),
                text_encoder_id=COSMOS_TEXT_ENCODER_ID,
                notes="base for fine-tuning: loads as an OSCAR model with a zero skeleton embedder (PE_s)",
            ),
            CheckpointSpec(
                name="oscar-2b",
                repo_id="zywu2115/OSCAR-2B",
                revision=None,
                kind="oscar",
                license=None,
                paper="OSCAR: Omni-Embodiment Action-Conditioned World Model for Robotics "
                "(https://wuzy2115.github.io/oscar-project-page/)",
                embodiments=("franka", "kuka", "agibot_g1", "hsr", "mano"),
                chunk_frames=81,
                width=512,
                height=288,
                fps=None,
                files=_OSCAR_LAYOUT,
                text_encoder_id=COSMOS_TEXT_ENCODER_ID,
                notes="the paper's release; file layout, license, commit and hashes unverified",
            ),
            CheckpointSpec(
                name="oscar-toy",
                repo_id="",
                revision=None,
                kind="oscar",
                license="Apache-2.0",
                paper="oscar's toy-world reproduction of OSCAR's central claim (docs/toyworld.md)",
                embodiments=("franka", "kuka", "toyarm"),
                chunk_frames=17,
                width=64,
                height=64,
                fps=10.0,
                files=(
                    FileSpec("README.md", "8d56c297843879440b875237ebe59f34b025d5e10937e5b3222e11bf8c13f0cf"),
                    FileSpec("oscar_manifest.json", "dd458a47bb259834d8d43d7d5f1a766ecd0f0ea0a5199a1a5f4a5333611b4452"),
                    FileSpec("oscar_model.json", "506281c49863b31a8483dfc7492317bc7ddb2f27064744c844102a0762c8cf23"),
                    FileSpec(
                        "text/empty_prompt_embeds.safetensors",
                        "315a414f568f65357cd9dd70dab0b3a573913300961246539db4ecbb13f595d2",
                    ),
                    FileSpec(
                        "tiny_decoder.safetensors",
                        "f62aafbbad3c6bf7d6107c21ae461b847432638f8feca67fca67294659ded303",
                    ),
                    FileSpec(
                        "tiny_encoder.safetensors",
                        "0aabca56e9663628c2b4109ab31f451dfaa68a0d881349f18431ae40ee432da8",
                    ),
                    FileSpec(
                        "transformer/config.json", "0e4008e3afadd739e070540ed4d672feef50dd74ee050d9e86db1fd7d1ca1bad"
                    ),
                    FileSpec(
                        "transformer/diffusion_pytorch_model.safetensors",
                        "e20f0c20e57931ff04422683ed2a563fabba0382888946a04ade2984512f5d55",
                    ),
                    FileSpec("vae/config.json", "750a9a1fad8678bcda27b417ac2aff7fe00779bbbd795af652fcdaee18daa9d6"),
                    FileSpec(
                        "vae/diffusion_pytorch_model.safetensors",
                        "1b3bb605c1316222e8c9e93249756185ee0c3493037905d546cc76c3819efa31",
                    ),
                ),
                text_encoder_id=None,
                notes="bundled: a small DiT + VAE trained on the procedural toy world on a CPU; not a model of real robots",
                bundled="assets/oscar-toy",
            ),
            CheckpointSpec(
                name="oscar-toy-fast",
                repo_id="",
                revision=None,
                kind="oscar",
                license="Apache-2.0",
                paper="a 4-step student of oscar-toy by guided progressive distillation (docs/distillation.md)",
                embodiments=("franka", "kuka", "toyarm"),
                chunk_frames=17,
                width=64,
                height=64,
                fps=10.0,
                files=(
                    FileSpec("README.md", "0c83a68884a65d61ef14bb6085a32839748013230e9455793d377b3e26d2c328"),
                    FileSpec("oscar_manifest.json", "5cbdd54b131b5765ff890fd30108f9de4b1df0d4beee8ea60edd27cfb66bf579"),
                    FileSpec("oscar_model.json", "baaab37b75233e128edfff6a4f52aa0566699bfbb4f700c705caf61b5a159efc"),
                    FileSpec(
                        "scheduler/scheduler_config.json",
                        "b3416cc4dcce0bc0b4f85b5581e89b5c713c61cb60bc638b71b83f24a81d78af",
                    ),
                    FileSpec(
                        "text/empty_prompt_embeds.safetensors",
                        "315a414f568f65357cd9dd70dab0b3a573913300961246539db4ecbb13f595d2",
                    ),
                    FileSpec(
                        "transformer/config.json",
                        "0e4008e3afadd739e070540ed4d672feef50dd74ee050d9e86db1fd7d1ca1bad",
                    ),
                    FileSpec(
                        "transformer/diffusion_pytorch_model.safetensors",
                        "9a8dcf5e3381ec04dee6f5a022050481c094d1d62d9e1c56b3092e249bae1dd2",
                    ),
                    FileSpec("vae/config.json", "750a9a1fad8678bcda27b417ac2aff7fe00779bbbd795af652fcdaee18daa9d6"),
                    FileSpec(
                        "vae/diffusion_pytorch_model.safetensors",
                        "1b3bb605c1316222e8c9e93249756185ee0c3493037905d546cc76c3819efa31",
                    ),
                ),
                text_encoder_id=None,
                notes="bundled: oscar-toy distilled to 4 DiT evaluations per chunk (guidance folded in); not a model of real robots",
                bundled="assets/oscar-toy-fast",
            ),
        ),
        key=lambda spec: spec.name,
    )
)
