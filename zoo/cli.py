"""The ``oscar zoo`` sub-commands (list, pull, convert) and ``oscar encode-prompt`` (the text encoder a zoo model
names): the commands that find models by zoo name, on the zoo's floor (``oscar rollout`` is
:mod:`oscar_core.model.cli`'s). Wired into the main parser by ``add_zoo_parsers(subparsers)``; each leaf parser
sets ``func`` (returns an exit code). Heavy imports happen inside the commands, so ``oscar --help`` stays fast.
"""

from __future__ import annotations

import argparse
import json
import sys

from oscar_core._util.arg_types import default_device, device
from oscar_core._util.outputs import output_option

__all__ = ["add_zoo_parsers", "cmd_zoo_list", "cmd_zoo_pull", "cmd_zoo_convert", "cmd_encode_prompt"]

ZOO_EXAMPLES = """examples:
  oscar zoo list
  oscar zoo list --json
  oscar zoo pull oscar-2b
  HF_HUB_OFFLINE=1 oscar zoo pull oscar-2b     (check that the cache holds it)
  oscar zoo convert ./cosmos-native-folder ./oscar-folder     (any layout -> oscar's, safetensors)
"""

ENCODE_EXAMPLES = """examples:
  oscar encode-prompt "put the cup in the sink" --model oscar-2b
  oscar encode-prompt "" --model cosmos-predict2.5-2b            (the empty-prompt embedding)
  oscar encode-prompt "wave" --encoder ./cosmos-pipeline-folder --out wave.safetensors --json

The embedding (1, 512, 100352 for Cosmos-Reason1) goes into the prompt cache
keyed by prompt and encoder revision; `oscar rollout --prompt` reads it there.
"""

_DTYPES = ("float32", "bfloat16", "float16")


def _add_zoo_parser(subparsers, fmt) -> None:
    """Register ``oscar zoo`` and its options on ``subparsers``."""
    z = subparsers.add_parser(
        "zoo", help="named world-model checkpoints: list, pull", epilog=ZOO_EXAMPLES, formatter_class=fmt
    )
    zsub = z.add_subparsers(dest="zoo_command", required=True)
    zl = zsub.add_parser(
        "list", help="the zoo table and your registered models", epilog=ZOO_EXAMPLES, formatter_class=fmt
    )
    zl.add_argument("--json", action="store_true", help="machine-readable output")
    zl.set_defaults(func=cmd_zoo_list)
    zp = zsub.add_parser(
        "pull", help="download and verify a checkpoint into the Hub cache", epilog=ZOO_EXAMPLES, formatter_class=fmt
    )
    zp.add_argument("name", help="zoo name, Hub id owner/name, or folder")
    zp.add_argument("--revision", help="Hub revision overriding the pinned one")
    zp.add_argument("--force", action="store_true", help="download again even if cached (after a corruption)")
    zp.add_argument("--offline", action="store_true", help="only check the local cache")
    zp.add_argument("--json", action="store_true", help="machine-readable output")
    zp.add_argument("--native-file", help="which native Cosmos checkpoint file, when the repo holds several")
    zp.set_defaults(func=cmd_zoo_pull)
    zc = zsub.add_parser(
        "convert",
        help="write any checkpoint layout (oscar, diffusers, native Cosmos) as oscar's (safetensors)",
        epilog=ZOO_EXAMPLES,
        formatter_class=fmt,
    )
    zc.add_argument("src", help="zoo name, Hub id owner/name, or folder, in any supported layout")
    output_option(zc.add_argument("dst", help="output folder (oscar layout)"), "folder")
    zc.add_argument("--revision", help="Hub revision")
    zc.add_argument("--native-file", help="which native Cosmos checkpoint file, when SRC holds several")
    zc.add_argument("--offline", action="store_true", help="only the local cache")
    zc.add_argument("--json", action="store_true", help="machine-readable output")
    zc.set_defaults(func=cmd_zoo_convert)


def _add_encode_prompt_parser(subparsers, fmt) -> None:
    """Register ``oscar encode-prompt`` and its options on ``subparsers``."""
    e = subparsers.add_parser(
        "encode-prompt",
        help="compute (and cache) the text embedding of a prompt",
        epilog=ENCODE_EXAMPLES,
        formatter_class=fmt,
    )
    e.add_argument("prompt", help='the prompt text ("" for the empty prompt)')
    e.add_argument("--model", help="zoo name / Hub id whose text_encoder_id to use (default: cosmos-predict2.5-2b's)")
    e.add_argument(
        "--encoder",
        metavar="ID_OR_FOLDER",
        help="text encoder: 'owner/name@revision:text_encoder' or a "
        "diffusers pipeline folder (text_encoder/ + tokenizer/)",
    )
    output_option(
        e.add_argument("--out", help="also write the embedding here (.safetensors, tensor 'prompt_embeds')"), "file"
    )
    output_option(e.add_argument("--prompt-cache", metavar="DIR", help="prompt-embedding cache folder"), "folder")
    e.add_argument("--device", type=device, help="torch device (default: cuda when available, else cpu)")
    e.add_argument("--dtype", choices=_DTYPES, help="encoder dtype (default: the checkpoint's)")
    e.add_argument("--offline", action="store_true", help="only the local Hub cache")
    e.add_argument("--json", action="store_true", help="machine-readable output")
    e.set_defaults(func=cmd_encode_prompt)


def add_zoo_parsers(subparsers) -> None:
    """Add ``zoo {list,pull,convert}`` and ``encode-prompt`` to an ``argparse`` sub-parser set."""
    fmt = argparse.RawDescriptionHelpFormatter
    _add_zoo_parser(subparsers, fmt)
    _add_encode_prompt_parser(subparsers, fmt)


# --------------------------------------------------------------------------- zoo


def cmd_zoo_list(args) -> int:
    import oscar_zoo

    specs = oscar_zoo.list_models()
    if args.json:
        print(json.dumps({"models": [s.row() for s in specs], "registry": str(oscar_zoo.registry_path())}, indent=2))
        return 0
    header = ("name", "repo@revision", "kind", "license", "embodiments", "frames", "size", "fps")
    rows = [header]
    for s in specs:
        where = "bundled with oscar-wm" if s.bundled else f"{s.repo_id}@{s.revision or 'main (unpinned)'}"
        rows.append(
            (
                s.name,
                where,
                s.kind,
                s.license or "?",
                ",".join(s.embodiments) or "-",
                str(s.chunk_frames or "?"),
                f"{s.width}x{s.height}" if s.width and s.height else "?",
                f"{s.fps:g}" if s.fps else "?",
            )
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    for row in rows:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip())
    print(f"user registry: {oscar_zoo.registry_path()}", file=sys.stderr)
    return 0


def cmd_zoo_pull(args) -> int:
    import oscar_zoo
    from oscar_zoo._hub import lock_path

    folder = oscar_zoo.pull(
        args.name,
        args.revision,
        force_download=args.force,
        local_files_only=True if args.offline else None,
        native_file=args.native_file,
    )
    resolved = oscar_zoo.resolve(args.name, args.revision)
    lock = lock_path(resolved.spec.repo_id, resolved.revision) if resolved.spec is not None else None
    lock = lock if lock is not None and lock.is_file() else None
    if args.json:
        print(json.dumps({"name": args.name, "folder": str(folder), "lock": str(lock) if lock else None}))
    else:
        print(f"{args.name}: verified, in {folder}" + (f" (pinned in {lock})" if lock else ""))
    return 0


def cmd_zoo_convert(args) -> int:
    import oscar_zoo
    from oscar_zoo._fetch import fetch, resolve

    report: list[str] = []
    got = fetch(
        resolve(args.src, args.revision), local_files_only=True if args.offline else None, native_file=args.native_file
    )
    out = oscar_zoo.convert(got.folder, args.dst, native_file=args.native_file, report=report)
    if args.json:
        print(json.dumps({"src": args.src, "dst": str(out), "layout": got.layout.kind, "report": report}, indent=2))
    else:
        for line in report:
            print(line, file=sys.stderr)
        print(f"{args.src} ({got.layout.kind}) -> {out} (oscar layout, safetensors)")
    return 0


# --------------------------------------------------------------------------- text


def _encoder_id_for(model: str | None) -> str:
    import oscar_zoo

    if model:
        spec = oscar_zoo.resolve(model).spec
        if spec is not None and spec.text_encoder_id:
            return spec.text_encoder_id
        from oscar_core.model.errors import ModelInputError

        raise ModelInputError(
            f"model {model!r}: expected a zoo entry with a text_encoder_id, found none; pass --encoder ID_OR_FOLDER"
        )
    return oscar_zoo.COSMOS_TEXT_ENCODER_ID


def cmd_encode_prompt(args) -> int:
    from oscar_core.model.rollout_files import text_encoder
    from oscar_core.model.text import PromptEmbeddingCache

    encoder_id = args.encoder or _encoder_id_for(args.model)
    cache = PromptEmbeddingCache(args.prompt_cache, encoder_id=encoder_id)
    embeds = cache.get(args.prompt)
    cached = embeds is not None
    if not cached:
        encoder = text_encoder(encoder_id, args.device or default_device(), args.dtype, args.offline)
        cache = PromptEmbeddingCache(args.prompt_cache, encoder_id=encoder.encoder_id)
        embeds, cached = encoder.cached(args.prompt, args.prompt_cache)
    summary = {
        "prompt": args.prompt,
        "encoder_id": cache.encoder_id,
        "shape": list(embeds.shape),
        "cache_file": str(cache.path(args.prompt)),
        "was_cached": cached,
    }
    if args.out:
        from safetensors.torch import save_file

        from oscar_core._util.atomic import atomic_output

        with atomic_output(args.out) as tmp:
            save_file(
                {"prompt_embeds": embeds.contiguous()},
                str(tmp),
                metadata={"prompt": args.prompt, "encoder_id": cache.encoder_id},
            )
        summary["out"] = str(args.out)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        how = "from the cache" if cached else "computed and cached"
        print(f"{args.prompt!r}: {tuple(embeds.shape)} {how} in {summary['cache_file']}")
    return 0
