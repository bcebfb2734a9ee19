"""LeRobot policies in the loop: :class:`LeRobotPolicy` speaks oscar's policy protocol around a LeRobot policy.

A LeRobot policy (``lerobot.policies.*``) is called as ``policy.select_action(batch)`` with a batch of tensors
under its input features' keys — ``observation.images.<camera>`` (float (1, 3, H, W) in [0, 1]),
``observation.state`` (float (1, S)) — and ``task`` (a list of one string); it returns one action, (1, D). Its
``config.input_features`` / ``config.output_features`` declare the keys and shapes; ``reset()`` clears its action
queue at the start of an episode.

The adapter maps oscar's observation to that batch through a declared mapping, ``{LeRobot key: oscar field(s)}``
(fields of :data:`~oscar_core.policy.protocol.OBS_FIELDS`): an image feature takes ``image`` or ``wrist_image``
(the wrist view is black: the world model generates one view), resized to the feature's size with area
interpolation; a state feature takes the listed numeric fields concatenated in order (default
``joint_position`` then ``gripper_position``: (J + 1,)); ``task`` always receives the prompt. Keys the
declared mapping does not name are derived from the features: the only image feature, or a feature whose key
names ``wrist``, and ``observation.state``. A feature the mapping does not cover, or a state whose width differs from the feature's,
is refused in one line naming the key. Each ``infer`` returns ``{"actions": (1, D)}``: one ``select_action``, so
declare ``actions_per_call: 1`` (the policy's own queue plays its chunks, as in LeRobot's evaluation loop).

Sources: ``lerobot:PATH_OR_REPO`` (:func:`load_lerobot_policy`; the mapping may follow as a query,
``lerobot:user/act_x?observation.images.top=image&observation.state=joint_position,gripper_position``).

Tested against a class with LeRobot's interface (tests/policy/test_policy_lerobot.py): ``lerobot`` 0.4.4, the
release current when this was written, pins torch < 2.11 and torchvision, so it does not install beside this
project's torch; :func:`load_lerobot_policy` follows its documented loading API and is not tested here.
"""

from __future__ import annotations

from collections.abc import Mapping
from urllib.parse import parse_qsl

import numpy as np

from ..errors import OscarError
from .protocol import DROID_KEYS, OBS_FIELDS

__all__ = ["LeRobotMappingError", "LeRobotPolicy", "default_mapping", "load_lerobot_policy", "parse_source"]

IMAGE_FIELDS = ("image", "wrist_image")
NUMERIC_FIELDS = ("joint_position", "gripper_position")


class LeRobotMappingError(OscarError, ValueError):
    """A LeRobot policy's input features and the declared mapping do not fit; one line naming the key."""


def _kind(feature) -> str:
    kind = getattr(feature, "type", None)
    return str(getattr(kind, "value", getattr(kind, "name", kind))).upper()


def default_mapping(input_features: Mapping) -> dict[str, tuple[str, ...]]:
    """The mapping derived from ``input_features`` ({key: feature with ``type`` and ``shape``}): the only image
    feature (or every one whose key names ``wrist``, the black wrist view) and ``observation.state`` (joint
    positions then gripper closure). Features it cannot place are left out (:func:`check_mapping` names them)."""
    out: dict[str, tuple[str, ...]] = {}
    images = [k for k, f in input_features.items() if _kind(f) == "VISUAL"]
    wrist = [k for k in images if "wrist" in k.lower()]
    scene = [k for k in images if k not in wrist]
    for k in wrist:
        out[k] = ("wrist_image",)
    if len(scene) == 1:
        out[scene[0]] = ("image",)
    if "observation.state" in input_features:
        out["observation.state"] = NUMERIC_FIELDS
    return out


def check_mapping(input_features: Mapping, mapping: Mapping, source: str) -> dict[str, tuple[str, ...]]:
    """The mapping as ``{key: tuple of fields}``, every input feature covered and every field known; else
    :class:`LeRobotMappingError` naming the key."""
    norm = {k: (v,) if isinstance(v, str) else tuple(v) for k, v in mapping.items()}
    for key, feature in input_features.items():
        if key not in norm:
            raise LeRobotMappingError(
                f"{source}: input feature {key!r} ({_kind(feature)}, shape {tuple(feature.shape)}): expected an "
                f"oscar field mapped to it ({key}=image, wrist_image or joint_position,gripper_position), found none"
            )
    for key, fields in norm.items():
        if key not in input_features:
            raise LeRobotMappingError(
                f"{source}: mapping key {key!r}: expected one of the policy's input features "
                f"{sorted(input_features)}, found it absent"
            )
        kind = _kind(input_features[key])
        allowed = IMAGE_FIELDS if kind == "VISUAL" else NUMERIC_FIELDS
        bad = [f for f in fields if f not in allowed]
        if not fields or bad or (kind == "VISUAL" and len(fields) != 1):
            want = "one of " + ", ".join(IMAGE_FIELDS) if kind == "VISUAL" else "some of " + ", ".join(NUMERIC_FIELDS)
            raise LeRobotMappingError(f"{source}: mapping {key!r}: expected {want}, found {list(fields)}")
    return norm


class LeRobotPolicy:
    """oscar's policy protocol (``infer(obs) -> {"actions": (1, D)}``, ``reset()``) around a LeRobot policy.

    policy: an object with ``select_action(batch)``, ``reset()`` and ``config.input_features`` /
    ``config.output_features``; mapping: ``{LeRobot key: oscar field or fields}`` over :func:`default_mapping`
    (its keys replace the derived ones);
    keys: the observation keys the loop sends (the policy declaration's ``keys``, DROID's by default);
    preprocess / postprocess: LeRobot's processor pipelines (batch → batch, action → action) or None;
    source: named in errors.
    """

    def __init__(self, policy, *, mapping=None, keys=None, preprocess=None, postprocess=None, source="<lerobot>"):
        config = getattr(policy, "config", None)
        features = getattr(config, "input_features", None)
        outputs = getattr(config, "output_features", None)
        if not isinstance(features, Mapping) or not isinstance(outputs, Mapping) or "action" not in outputs:
            raise LeRobotMappingError(
                f"{source}: config: expected input_features and output_features with 'action' (a LeRobot "
                f"policy), found {type(config).__name__}"
            )
        self.policy, self.source = policy, source
        self.features = dict(features)
        self.mapping = check_mapping(self.features, {**default_mapping(features), **(mapping or {})}, source)
        self.keys = {**DROID_KEYS, **(keys or {})}
        self.action_width = int(np.prod(tuple(outputs["action"].shape)))
        self.preprocess, self.postprocess = preprocess, postprocess

    def reset(self) -> None:
        self.policy.reset()

    def batch(self, obs: Mapping) -> dict:
        """LeRobot's batch for oscar's observation ``obs`` (module docstring)."""
        import cv2
        import torch

        device = next((p.device for p in getattr(self.policy, "parameters", lambda: iter(()))()), "cpu")
        out: dict = {}
        for key, fields in self.mapping.items():
            shape = tuple(self.features[key].shape)
            if _kind(self.features[key]) == "VISUAL":
                c, h, w = shape
                image = np.asarray(obs[self.keys[fields[0]]], dtype=np.uint8)
                if image.shape[:2] != (h, w):
                    image = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
                chw = torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1))).float().div_(255.0)
                out[key] = chw[None].to(device)
            else:
                state = np.concatenate([np.asarray(obs[self.keys[f]], dtype=np.float64).ravel() for f in fields])
                if state.shape != shape:
                    raise LeRobotMappingError(
                        f"{self.source}: input feature {key!r}: expected shape {shape}, found {state.shape} from "
                        f"{' + '.join(fields)}"
                    )
                out[key] = torch.from_numpy(state.astype(np.float32))[None].to(device)
        out["task"] = [str(obs.get(self.keys["prompt"], ""))]
        return out

    def act(self, obs: Mapping) -> np.ndarray:
        """One action (D,) float64 for ``obs``: ``select_action`` of the mapped batch."""
        import torch

        batch = self.batch(obs)
        if self.preprocess is not None:
            batch = self.preprocess(batch)
        with torch.inference_mode():
            action = self.policy.select_action(batch)
        if self.postprocess is not None:
            action = self.postprocess(action)
        return np.asarray(action.detach().cpu().numpy() if hasattr(action, "detach") else action, np.float64).ravel()

    def infer(self, obs: dict) -> dict:
        return {"actions": self.act(obs)[None]}


def parse_source(source: str) -> tuple[str, dict[str, tuple[str, ...]] | None]:
    """``lerobot:PATH_OR_REPO[?key=field[,field]&...]`` → (path or repo id, mapping or None)."""
    body = source.removeprefix("lerobot:")
    where, _, query = body.partition("?")
    if not where:
        raise LeRobotMappingError(f"{source}: expected lerobot:PATH_OR_REPO, found no path")
    if not query:
        return where, None
    mapping = {}
    for key, value in parse_qsl(query, keep_blank_values=True, strict_parsing=False):
        fields = tuple(v for v in value.split(",") if v)
        unknown = [f for f in fields if f not in OBS_FIELDS]
        if unknown or not fields:
            raise LeRobotMappingError(
                f"{source}: mapping {key!r}: expected fields of {list(OBS_FIELDS)}, found {value!r}"
            )
        mapping[key] = fields
    return where, mapping


def load_lerobot_policy(source: str, keys=None) -> LeRobotPolicy:
    """A :class:`LeRobotPolicy` from ``lerobot:PATH_OR_REPO[?mapping]``: the config and weights through LeRobot's
    own ``from_pretrained`` (a folder, or a Hub repo LeRobot downloads), with its pre/post processors where the
    installed LeRobot has them. Needs the ``lerobot`` package (``pip install lerobot``)."""
    where, mapping = parse_source(source)
    try:
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class
    except ImportError as exc:
        raise ImportError(
            f"lerobot is needed here and is not installed ({exc}); install it with: pip install lerobot "
            "(it pins torch < 2.11 and torchvision)"
        ) from None
    config = PreTrainedConfig.from_pretrained(where)
    policy = get_policy_class(config.type).from_pretrained(where)
    policy.eval()
    pre = post = None
    try:
        from lerobot.policies.factory import make_pre_post_processors
    except ImportError:
        pass
    else:
        pre, post = make_pre_post_processors(policy.config, pretrained_path=where)
    return LeRobotPolicy(policy, mapping=mapping, keys=keys, preprocess=pre, postprocess=post, source=source)
