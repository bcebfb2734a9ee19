"""``torchrun --nproc-per-node N -m oscar_core.train CONFIG.yaml``: the same as ``oscar train``, one process per rank."""

from __future__ import annotations

import sys

from ..errors import OscarError
from .cli import build_train_parser


def main(argv=None) -> int:
    args = build_train_parser().parse_args(argv)
    try:
        return args.func(args)
    except (OscarError, ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        from .._interrupt import report

        return report(exc, args)


if __name__ == "__main__":
    sys.exit(main())
