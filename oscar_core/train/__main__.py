"""``torchrun --nproc-per-node N -m oscar_core.train CONFIG.yaml``: the same as ``oscar train``, one process per rank."""

from __future__ import annotations

import sys

from ..errors import OscarError
from .cli import build_train_parser


def main(argv=None) -> int:
    from .._util.interrupt import interrupted, noting_interrupts, report

    args = build_train_parser().parse_args(argv)
    with noting_interrupts():
        try:
            return args.func(args)
        except KeyboardInterrupt as exc:
            return report(exc, args)
        except (OscarError, ValueError, FileNotFoundError) as exc:
            if interrupted():
                return report(KeyboardInterrupt(), args)
            print(f"error: {exc}", file=sys.stderr)
            return 2


if __name__ == "__main__":
    sys.exit(main())
