"""openpi's websocket policy protocol: a client that is a policy, and a server for any policy object.

The wire format is openpi-client's (``openpi_client.websocket_client_policy`` / ``msgpack_numpy``), so a policy
served by openpi's ``serve_policy.py`` answers :class:`WebsocketPolicy`, and a policy served by
:func:`serve_policy` answers openpi's client:

* on connect the server sends one binary message: the msgpack of its metadata map;
* then each request is the msgpack of the observation dict, each answer the msgpack of the result dict;
* numpy arrays travel as maps ``{b"__ndarray__": True, b"data": bytes, b"dtype": dtype.str, b"shape": shape}``
  (scalars as ``{b"__npgeneric__": True, b"data": value, b"dtype": ...}``);
* a *text* message from the server is an error (its traceback); the server then closes the connection.

A policy is served by ``python -m oscar_core.policy.serve module:attr --port 8000``.
openpi's protocol has no ``reset`` message: :meth:`WebsocketPolicy.reset` opens a fresh connection, so each
episode starts with a server-side handler of its own. Needs ``msgpack`` and ``websockets``
(``pip install "oscar-wm[policy]"``); openpi-client itself is not needed (it pins numpy < 2).
"""

from __future__ import annotations

import functools
import traceback

import numpy as np

from .._util.optional import require

__all__ = ["pack", "unpack", "WebsocketPolicy", "serve_policy"]


def _pack_array(obj):
    if isinstance(obj, (np.ndarray, np.generic)) and obj.dtype.kind in ("V", "O", "c"):
        raise ValueError(f"cannot send an array of dtype {obj.dtype}")
    if isinstance(obj, np.ndarray):
        return {
            b"__ndarray__": True,
            b"data": np.ascontiguousarray(obj).tobytes(),
            b"dtype": obj.dtype.str,
            b"shape": obj.shape,
        }
    if isinstance(obj, np.generic):
        return {b"__npgeneric__": True, b"data": obj.item(), b"dtype": obj.dtype.str}
    return obj


def _unpack_array(obj):
    if b"__ndarray__" in obj:
        return np.ndarray(buffer=obj[b"data"], dtype=np.dtype(obj[b"dtype"]), shape=obj[b"shape"])
    if b"__npgeneric__" in obj:
        return np.dtype(obj[b"dtype"]).type(obj[b"data"])
    return obj


def pack(obj) -> bytes:
    """msgpack bytes of ``obj`` with numpy arrays as openpi encodes them."""
    msgpack = require("msgpack", "policy")
    return msgpack.packb(obj, default=_pack_array)


def unpack(data: bytes):
    """The object of openpi-encoded msgpack ``data`` (arrays back as read-only numpy arrays)."""
    msgpack = require("msgpack", "policy")
    return msgpack.unpackb(data, object_hook=_unpack_array)


class WebsocketPolicy:
    """A policy behind openpi's websocket protocol at ``uri`` (``ws://host:port``); ``infer`` sends the
    observation and returns the server's answer; a server error (text message) raises ``RuntimeError`` with its
    first line. ``open_timeout``: seconds to connect."""

    def __init__(self, uri: str, open_timeout: float = 10.0):
        self.uri, self.open_timeout = uri, open_timeout
        self._ws = None
        self.metadata = None
        self._connect()

    def _connect(self) -> None:
        client = require("websockets.sync.client", "policy")
        if self._ws is not None:
            self._ws.close()
        import inspect

        options = dict(compression=None, max_size=None, open_timeout=self.open_timeout)
        known = inspect.signature(client.connect).parameters
        if "legacy" in known:  # websockets >= 16: connect directly, not as a context manager
            options["legacy"] = True
        if "proxy" in known:  # never through an HTTP proxy of the environment
            options["proxy"] = None
        self._ws = client.connect(self.uri, **options)
        self.metadata = unpack(self._ws.recv())

    def reset(self) -> None:
        """A fresh connection (A policy is served by ``python -m oscar_core.policy.serve module:attr --port 8000``.
        openpi's protocol has no reset message)."""
        self._connect()

    def infer(self, obs: dict) -> dict:
        self._ws.send(pack(obs))
        answer = self._ws.recv()
        if isinstance(answer, str):
            raise RuntimeError(f"policy server error: {answer.strip().splitlines()[-1] if answer.strip() else ''}")
        return unpack(answer)

    def close(self) -> None:
        if self._ws is not None:
            self._ws.close()
            self._ws = None


def _handler(policy_factory, metadata: dict, ws) -> None:
    """One connection: its own policy object (so episodes on parallel connections do not share state)."""
    policy = policy_factory()
    if hasattr(policy, "reset"):
        policy.reset()
    ws.send(pack(metadata))
    while True:
        try:
            obs = unpack(ws.recv())
        except Exception:  # noqa: BLE001 - the client went away
            return
        try:
            ws.send(pack(policy.infer(obs)))
        except Exception:  # noqa: BLE001 - the error goes to the client as text, as openpi's server does
            ws.send(traceback.format_exc())
            ws.close()
            return


def serve_policy(
    policy_factory, host: str = "127.0.0.1", port: int = 8000, metadata: dict | None = None, ready=None
) -> None:
    """Serve a fresh ``policy_factory()`` per connection over openpi's protocol until interrupted; ``ready`` (a
    callable) receives the bound port once listening."""
    server_mod = require("websockets.sync.server", "policy")
    handler = functools.partial(_handler, policy_factory, metadata or {})
    with server_mod.serve(handler, host, port, compression=None, max_size=None) as server:
        if ready is not None:
            ready(server.socket.getsockname()[1])
        server.serve_forever()
