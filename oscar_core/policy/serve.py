"""``python -m oscar_core.policy.serve module:attr [--host H] [--port P]``: serve a policy over openpi's
websocket protocol (:func:`oscar_core.policy.remote.serve_policy`), a fresh policy object per connection.

A policy that cannot be loaded (a typo in its path, a missing class) or a missing ``policy`` extra is one line
on stderr, ``error: …``, and exit code 2, before anything listens."""

from __future__ import annotations

import argparse
import sys

from .loading import load_policy
from .protocol import PolicySpecError

__all__ = ["main"]


def main(argv=None) -> int:
    """``python -m oscar_core.policy.serve module:attr [--host H] [--port P]``: serve a policy; prints
    ``listening on ws://H:P`` once ready (port 0: a free port)."""
    p = argparse.ArgumentParser(
        prog="python -m oscar_core.policy.serve",
        description="serve a policy (module:attr, file.py:attr or an oscar.policies entry "
        "point) over openpi's websocket protocol",
    )
    p.add_argument("policy")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    args = p.parse_args(argv)
    try:
        from .._util.optional import require

        require("msgpack", "policy")
        require("websockets", "policy")
        from .remote import serve_policy

        load_policy(args.policy)  # fail before listening when the policy cannot be loaded
    except (ImportError, PolicySpecError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    def ready(port: int) -> None:
        print(f"listening on ws://{args.host}:{port}", flush=True)

    serve_policy(lambda: load_policy(args.policy), args.host, args.port, {"policy": args.policy}, ready=ready)
    return 0


if __name__ == "__main__":
    sys.exit(main())
