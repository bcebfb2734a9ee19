"""Plugin discovery: entry points, one-file plugins, broken plugins, the contract."""

import inspect
import re
import textwrap
from pathlib import Path

import pytest
from _paths import REPO

from oscar_core.errors import PluginError
from oscar_core.plugin import hookspecs
from oscar_core.plugin.registry import Registry

TOYARM_URDF = REPO / "examples" / "oscar-toyarm" / "oscar_toyarm" / "assets" / "toyarm.urdf"

GOOD_MODULE = f'''
from oscar_core import Embodiment, Skeleton, hookimpl

class {{cls}}(Embodiment):
    name = "{{name}}"
    urdf = r"{TOYARM_URDF}"
    skeleton = Skeleton(links=({{links}}))

@hookimpl
def oscar_register_embodiments():
    return [{{cls}}]
'''


def good_module(name, cls="Robot", links='"base_link", "upper_arm", "tool"'):
    return GOOD_MODULE.format(name=name, cls=cls, links=links)


def fake_distribution(root: Path, dist: str, version: str, modules: dict[str, str], entry_points: dict[str, str]):
    """Install a distribution the way pip lays it out: modules + a .dist-info with entry_points.txt."""
    for mod, source in modules.items():
        (root / f"{mod}.py").write_text(textwrap.dedent(source))
    info = root / f"{dist.replace('-', '_')}-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n")
    eps = "".join(f"{k} = {v}\n" for k, v in entry_points.items())
    (info / "entry_points.txt").write_text(f"[oscar]\n{eps}")


@pytest.fixture
def site(tmp_path, monkeypatch):
    root = tmp_path / "site"
    root.mkdir()
    monkeypatch.syspath_prepend(str(root))
    for var in ("OSCAR_PLUGINS", "OSCAR_DISABLE_PLUGIN_AUTOLOAD", "OSCAR_BLOCK_PLUGINS"):
        monkeypatch.delenv(var, raising=False)
    return root


def test_entry_point_plugin_is_found_with_its_distribution(site):
    fake_distribution(site, "oscar-alpha", "1.2.3", {"oscar_alpha": good_module("alpha")}, {"alpha": "oscar_alpha"})
    reg = Registry(warn=False)
    entry = reg.entries["alpha"]
    assert (entry.distribution, entry.version, entry.plugin) == ("oscar-alpha", "1.2.3", "alpha")
    emb = reg.get("alpha")
    assert emb.edges == (("base_link", "upper_arm"), ("upper_arm", "tool"))


def test_builtin_example_plugin_registers_through_the_same_group():
    reg = Registry(warn=False)
    assert reg.entries["toyarm"].distribution == "oscar-toyarm"


def test_broken_plugins_are_reported_and_others_still_load(site):
    fake_distribution(site, "oscar-good", "1.0", {"oscar_good": good_module("good")}, {"good": "oscar_good"})
    fake_distribution(
        site,
        "oscar-broken-import",
        "0.1",
        {"oscar_broken": "import does_not_exist_anywhere\n"},
        {"broken": "oscar_broken"},
    )
    fake_distribution(
        site,
        "oscar-raises",
        "0.2",
        {
            "oscar_raises": """
        from oscar_core import hookimpl
        @hookimpl
        def oscar_register_embodiments():
            raise RuntimeError("boom")
        """
        },
        {"raises": "oscar_raises"},
    )
    fake_distribution(
        site,
        "oscar-badclass",
        "0.3",
        {
            "oscar_badclass": """
        from oscar_core import Embodiment, hookimpl
        class Bad(Embodiment):
            name = "Bad Name"
        @hookimpl
        def oscar_register_embodiments():
            return [Bad, int]
        """
        },
        {"badclass": "oscar_badclass"},
    )
    fake_distribution(
        site, "oscar-zdupe", "9.9", {"oscar_dupe": good_module("good", cls="Again")}, {"dupe": "oscar_dupe"}
    )
    fake_distribution(
        site,
        "oscar-badhook",
        "0.4",
        {
            "oscar_badhook": """
        from oscar_core import hookimpl
        @hookimpl
        def oscar_register_embodiments(unexpected_argument):
            return []
        """
        },
        {"badhook": "oscar_badhook"},
    )
    with pytest.warns(UserWarning):
        reg = Registry()
    assert "good" in reg.names()
    errors = {}
    for f in reg.failures:
        errors[f.distribution.split()[0]] = errors.get(f.distribution.split()[0], "") + f.error + "\n"
    assert "does_not_exist_anywhere" in errors["oscar-broken-import"]
    assert "RuntimeError: boom" in errors["oscar-raises"]
    assert "lowercase identifier" in errors["oscar-badclass"] and "skeleton" in errors["oscar-badclass"]
    assert "oscar-good 1.0" in errors["oscar-zdupe"] and "oscar-zdupe 9.9" in errors["oscar-zdupe"]
    assert "unexpected_argument" in errors["oscar-badhook"]
    assert any("Embodiment subclass" in f.error and "int" in f.error for f in reg.failures)
    assert reg.entries["good"].distribution == "oscar-good"  # distributions load in name order; the first wins
    with pytest.raises(PluginError, match="unknown embodiment 'broken'.*oscar-broken-import"):
        reg.get("broken")


def test_contract_checked_against_the_urdf_names_the_distribution(site):
    fake_distribution(
        site,
        "oscar-wronglink",
        "2.0",
        {"oscar_wronglink": good_module("wronglink", links='"base_link", "no_such_link"')},
        {"wronglink": "oscar_wronglink"},
    )
    reg = Registry(warn=False)
    with pytest.raises(PluginError, match=r"(?s)'wronglink' from oscar-wronglink 2.0.*no_such_link"):
        reg.get("wronglink")


def test_one_file_plugin_from_path_and_env(tmp_path, site, monkeypatch):
    one = tmp_path / "my_robot.py"
    one.write_text(good_module("myrobot"))
    reg = Registry(plugin_paths=[one], warn=False)
    assert reg.entries["myrobot"].distribution == f"file:{one.resolve()}"
    assert reg.get("myrobot").joint_names == ("base_yaw", "shoulder", "elbow", "wrist_pitch", "finger_left")
    folder = tmp_path / "plugins"
    folder.mkdir()
    (folder / "other.py").write_text(good_module("other"))
    monkeypatch.setenv("OSCAR_PLUGINS", f"{one}{__import__('os').pathsep}{folder}")
    reg = Registry(warn=False)
    assert {"myrobot", "other"} <= set(reg.names())


def test_broken_one_file_plugin(tmp_path, site):
    bad = tmp_path / "bad.py"
    bad.write_text("raise SystemExit('nope')\n")
    reg = Registry(plugin_paths=[bad, tmp_path / "missing.py"], warn=False)
    msgs = [str(f) for f in reg.failures]
    assert any("bad.py" in m and "SystemExit" in m for m in msgs)
    assert any("missing.py" in m and "existing .py file" in m for m in msgs)


def test_autoload_can_be_disabled_and_plugins_blocked(site, monkeypatch):
    fake_distribution(site, "oscar-alpha", "1.0", {"oscar_alpha": good_module("alpha")}, {"alpha": "oscar_alpha"})
    fake_distribution(
        site, "oscar-broken-import", "0.1", {"oscar_broken2": "raise ImportError('x')\n"}, {"broken": "oscar_broken2"}
    )
    monkeypatch.setenv("OSCAR_DISABLE_PLUGIN_AUTOLOAD", "1")
    assert Registry(warn=False).names() == []
    monkeypatch.delenv("OSCAR_DISABLE_PLUGIN_AUTOLOAD")
    monkeypatch.setenv("OSCAR_BLOCK_PLUGINS", "oscar-broken-import, toyarm")
    reg = Registry(warn=False)
    assert reg.failures == [] and "alpha" in reg.names() and "toyarm" not in reg.names()


def test_every_hook_is_documented_with_its_signature():
    docs = (REPO / "docs" / "write-a-plugin.md").read_text()
    hooks = [n for n, f in vars(hookspecs).items() if n.startswith("oscar_") and callable(f)]
    assert hooks, "no hooks found"
    for name in hooks:
        sig = f"{name}{inspect.signature(getattr(hookspecs, name))}"
        assert re.search(rf"^### `{re.escape(sig)}`$", docs, re.M), (
            f"hook {sig} is not documented in docs/write-a-plugin.md"
        )
