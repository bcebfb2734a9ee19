"""ConfiguredModule: constructor arguments as config, diffusers-layout folders written atomically and read strictly."""

import inspect
import json

import pytest
import torch

from oscar_core.model.configured import ConfiguredModule, ModelConfig, parse_shard_size
from oscar_core.model.errors import CheckpointLayoutError, ModelInputError
from oscar_core.model.weights import INDEX_NAME, WEIGHTS_NAME, build_strict, load_state_dict, read_config


class Base(ConfiguredModule):
    config_class_name = "BaseNet"

    def __init__(self, width: int = 4, depth: int = 2, scales: tuple[int, ...] = (1, 2)):
        super().__init__()
        self.layers = torch.nn.ModuleList(torch.nn.Linear(width, width) for _ in range(depth))


class Child(Base):
    config_class_name = "ChildNet"

    def __init__(self, width: int = 4, depth: int = 2, scales: tuple[int, ...] = (1, 2), extra: int | None = None):
        super().__init__(width=width, depth=depth, scales=scales)
        self.extra = torch.nn.Linear(width, extra or width, bias=False)


def test_config_records_every_argument_with_defaults_and_is_read_only():
    model = Base(8)
    assert dict(model.config) == {"width": 8, "depth": 2, "scales": (1, 2)}
    assert model.config.width == 8 and model.config["depth"] == 2
    with pytest.raises(AttributeError, match="read-only"):
        model.config.width = 3
    with pytest.raises(AttributeError, match="no setting 'nope'"):
        model.config.nope  # noqa: B018
    assert isinstance(model.config, ModelConfig)
    assert "config" not in dict(model.named_modules())


def test_subclass_records_its_own_signature():
    model = Child(width=6, extra=3)
    assert dict(model.config) == {"width": 6, "depth": 2, "scales": (1, 2), "extra": 3}
    assert Child.config_keys() == ["width", "depth", "scales", "extra"]


class FoldedChild(Base):
    """Child's settings, stating only its own new one; the rest reach Base through **kwargs."""

    config_class_name = "ChildNet"

    def __init__(self, *, extra: int | None = None, **kwargs):
        super().__init__(**kwargs)
        self.extra = torch.nn.Linear(self.config.width, extra or self.config.width, bias=False)


class FoldedGrandchild(FoldedChild):
    """Restates one parent setting with another default and adds one more."""

    def __init__(self, *, depth: int = 5, tag: str = "x", **kwargs):
        super().__init__(depth=depth, **kwargs)


def test_subclass_with_kwargs_records_its_parents_settings_as_a_spelled_out_one_does():
    for kwargs in ({}, {"width": 6, "extra": 3}, {"scales": (4,), "depth": 1}):
        folded, spelled = FoldedChild(**kwargs), Child(**kwargs)
        assert list(folded.config.items()) == list(spelled.config.items())
        assert list(folded.state_dict()) == list(spelled.state_dict())
    assert FoldedChild.config_keys() == Child.config_keys() == ["width", "depth", "scales", "extra"]
    assert list(inspect.signature(FoldedChild).parameters) == ["width", "depth", "scales", "extra"]
    assert dict(FoldedChild(7, 3).config) == {"width": 7, "depth": 3, "scales": (1, 2), "extra": None}
    grand = FoldedGrandchild(width=2)
    assert list(grand.config.items()) == [("width", 2), ("depth", 5), ("scales", (1, 2)), ("extra", None), ("tag", "x")]
    assert len(grand.layers) == 5


def test_subclass_with_kwargs_still_refuses_unknown_settings():
    with pytest.raises(CheckpointLayoutError, match="colour") as err:
        FoldedChild.from_config({"width": 5, "extra": 2, "colour": "red"}, source="some/config.json")
    assert "width, depth, scales, extra" in str(err.value)
    with pytest.raises(TypeError, match="colour"):
        FoldedChild(colour="red")
    with pytest.raises(TypeError, match="colour"):
        FoldedGrandchild(colour="red")


def test_from_config_drops_private_keys_and_refuses_unknown_ones():
    model = Base.from_config({"_class_name": "BaseNet", "_diffusers_version": "0.1", "width": 5, "scales": [3]})
    assert model.config.width == 5 and model.config.scales == [3]
    with pytest.raises(CheckpointLayoutError, match="colour") as err:
        Base.from_config({"width": 5, "colour": "red"}, source="some/config.json")
    assert "some/config.json" in str(err.value)


@pytest.mark.parametrize("shard", ["10GB", "200B", 100])
def test_save_then_strict_load_roundtrips_single_and_sharded(tmp_path, shard):
    torch.manual_seed(0)
    model = Child(width=4, depth=3, extra=2)
    model.save_pretrained(tmp_path / "m", max_shard_size=shard)
    files = sorted(p.name for p in (tmp_path / "m").iterdir())
    sharded = shard != "10GB"
    assert (INDEX_NAME in files) == sharded and (WEIGHTS_NAME in files) != sharded
    if sharded:
        index = json.loads((tmp_path / "m" / INDEX_NAME).read_text())
        assert set(index["weight_map"]) == set(model.state_dict())
        assert len(set(index["weight_map"].values())) > 1
    config = read_config(tmp_path / "m", ("ChildNet",))
    assert config["scales"] == [1, 2] and config["extra"] == 2
    back = build_strict(Child, config, load_state_dict(tmp_path / "m"), tmp_path / "m")
    for (k, a), (k2, b) in zip(model.state_dict().items(), back.state_dict().items(), strict=True):
        assert k == k2 and torch.equal(a, b)
    assert not [p for p in files if p.endswith(".tmp") or ".tmp." in p]


def test_resave_with_other_sharding_leaves_no_stale_weights(tmp_path):
    model = Base(width=4, depth=3)
    model.save_pretrained(tmp_path / "m", max_shard_size=100)
    model.save_pretrained(tmp_path / "m")
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == ["config.json", WEIGHTS_NAME]
    model.save_pretrained(tmp_path / "m", max_shard_size=100)
    names = sorted(p.name for p in (tmp_path / "m").iterdir())
    assert WEIGHTS_NAME not in names and INDEX_NAME in names


def test_folder_loads_in_diffusers_when_the_class_name_is_theirs(tmp_path):
    pytest.importorskip("diffusers")
    from diffusers import AutoencoderKLWan

    ref = AutoencoderKLWan(base_dim=8, z_dim=4, dim_mult=[1, 2], num_res_blocks=1, temperal_downsample=[True])

    class Wrapped(ConfiguredModule):
        config_class_name = "AutoencoderKLWan"

        def __init__(
            self, base_dim: int = 8, z_dim: int = 4, dim_mult=(1, 2), num_res_blocks=1, temperal_downsample=(True,)
        ):
            super().__init__()
            self.inner = ref

        def state_dict(self, *a, **k):
            return self.inner.state_dict(*a, **k)

    Wrapped().save_pretrained(tmp_path / "vae")
    back = AutoencoderKLWan.from_pretrained(tmp_path / "vae")
    assert back.config.base_dim == 8 and back.config.z_dim == 4
    for k, v in ref.state_dict().items():
        assert torch.equal(v, back.state_dict()[k])


def test_safe_serialization_false_is_refused(tmp_path):
    with pytest.raises(ModelInputError, match="safetensors"):
        Base().save_pretrained(tmp_path, safe_serialization=False)


@pytest.mark.parametrize(("text", "expected"), [("10GB", 10**10), ("200KB", 200_000), ("1GiB", 2**30), (7, 7)])
def test_parse_shard_size(text, expected):
    assert parse_shard_size(text) == expected


@pytest.mark.parametrize("bad", ["", "GB", "-1GB", "ten", 0, "1XB"])
def test_parse_shard_size_refuses_nonsense(bad):
    with pytest.raises(ModelInputError, match="max_shard_size"):
        parse_shard_size(bad)


def test_a_model_deep_copies_and_pickles_with_its_config():
    """copy.deepcopy (train-vae keeps a copy of the best weights) and pickle rebuild the config object without
    calling its constructor; reading its settings then must not recurse."""
    import copy
    import pickle

    model = Child(6, extra=3)
    for twin in (copy.deepcopy(model), pickle.loads(pickle.dumps(model))):
        assert dict(twin.config) == dict(model.config) and twin.config.extra == 3
        assert all(torch.equal(a, b) for a, b in zip(twin.state_dict().values(), model.state_dict().values()))
